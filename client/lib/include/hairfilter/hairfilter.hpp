// hairfilter.hpp: libhairfilter for C++11 and later, header only, over
// hairfilter.h.
//
//   hairfilter::Options opt;
//   opt.client_name = "my-engine";
//   hairfilter::Client hf("unix:/run/hairfilterd/hairfilterd.sock", opt);  // throws
//   hairfilter::Request r;
//   r.variant = "Base"; r.width = w; r.height = h; r.spp = 4;
//   r.set_features(features.data(), features.size() * sizeof(float));
//   if (reads_estimate) r.set_estimate(estimate.data(), estimate.size() * sizeof(float));
//   r.set_result(filtered.data(), filtered.size() * sizeof(float));
//   hairfilter::Status s = hf.filter(r);        // never throws
//   if (s.busy() || s.expired()) use_last_frame(); else if (!s) log(s.message);
//
// Setting up (connecting, listing, statistics, shared memory) throws
// hairfilter::Error when it fails, with the code and hfc_last_message's
// explanation; the per-frame calls (filter, submit, wait) return a Status
// instead, because BUSY (and EXPIRED, a frame given a budget,
// Request::deadline_us) is routine in a frame loop. Built without
// exceptions (-fno-exceptions), the throwing constructors are left out and
// Client::open and SharedBuffer::open give a Status.
//
// Client owns its connection and SharedBuffer its segment (RAII, movable,
// not copyable). A Client, like an hfc_client, is for one thread at a time.
// A SharedBuffer follows the connection, not the Client object: it stays
// valid when its Client is moved, and one that outlives the connection
// (members declared in either order, a Client moved into a shorter-lived
// owner) is simply forgotten, since hfc_close has unmapped it.
#ifndef HAIRFILTER_HPP
#define HAIRFILTER_HPP

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#if defined(__cpp_exceptions) || defined(__EXCEPTIONS)
#include <stdexcept>
#define HAIRFILTER_HPP_EXCEPTIONS 1
#endif

#include "hairfilter.h"

namespace hairfilter {

// The library's version at run time ("0.1.0"); HAIRFILTER_VERSION_STRING
// is the headers'.
inline std::string version() { return hfc_version(); }

// The outcome of a call: code HFC_OK (0) or a negative HFC_E_* code, and
// what hfc_last_message said about it.
struct Status {
  int code;
  std::string message;
  Status() : code(HFC_OK), message() {}
  Status(int c, std::string m) : code(c), message(std::move(m)) {}
  explicit operator bool() const { return code == HFC_OK; }
  bool busy() const { return code == HFC_E_BUSY; }
  // The frame's budget (Request::deadline_us) passed in the server's queue:
  // not computed, as routine in a frame loop under load as busy().
  bool expired() const { return code == HFC_E_EXPIRED; }
  // The frame was cancelled (Client::cancel) before it ran.
  bool cancelled() const { return code == HFC_E_CANCELLED; }
  // "server busy: ...: <message>"
  std::string what() const {
    std::string s = hfc_strerror(code);
    if (!message.empty()) s += ": " + message;
    return s;
  }
};

#ifdef HAIRFILTER_HPP_EXCEPTIONS
class Error : public std::runtime_error {
 public:
  explicit Error(const Status &s) : std::runtime_error(s.what()), code_(s.code) {}
  int code() const { return code_; }

 private:
  int code_;
};

inline void check(const Status &s) {
  if (!s) throw Error(s);
}
#endif

// hfc_options with every field at its default.
struct Options : hfc_options {
  Options() { hfc_options_init(this); }
};

// hfc_request with struct_size set and everything else zero.
struct Request : hfc_request {
  Request() { hfc_request_init(this); }
  void set_features(const void *p, std::size_t bytes) {
    features = p;
    features_bytes = bytes;
  }
  // The frame's alpha-corrected estimate, [height][width][3] in in_dtype,
  // from a buffer of its own (hfc_request.estimate_buffer): for a variant
  // that reads it (hfc_variant.estimate). nullptr: no estimate.
  void set_estimate(const void *p, std::size_t bytes) {
    estimate = p ? 1 : 0;
    estimate_buffer = p;
    estimate_bytes = bytes;
  }
  void set_result(void *p, std::size_t bytes) {
    result = p;
    result_bytes = bytes;
  }
  void set_rgba(void *p, std::size_t bytes) {
    rgba = p;
    rgba_bytes = bytes;
  }
};

class SharedBuffer;

class Client {
 public:
  Client() : c_() {}
#ifdef HAIRFILTER_HPP_EXCEPTIONS
  // Connects (url: one endpoint or a comma-separated list); throws Error.
  explicit Client(const std::string &url) : c_() { check(open(url, nullptr, *this)); }
  Client(const std::string &url, const hfc_options &opt) : c_() {
    check(open(url, &opt, *this));
  }
#endif
  // The connection is closed with the last Client it was moved through.
  Client(Client &&o) noexcept : c_(std::move(o.c_)) {}
  Client &operator=(Client &&o) noexcept {
    c_ = std::move(o.c_);
    return *this;
  }
  Client(const Client &) = delete;
  Client &operator=(const Client &) = delete;

  // Connects without throwing; out takes the connection on success.
  static Status open(const std::string &url, const hfc_options *opt, Client &out) {
    hfc_client *c = nullptr;
    int rc = hfc_connect(url.c_str(), opt, &c);
    if (rc) return Status(rc, hfc_last_message(nullptr));
    out = Client(c);
    return Status();
  }

  explicit operator bool() const { return c_ != nullptr; }
  hfc_client *get() const { return c_.get(); }
  // On an empty Client: an all-zero info, "", HFC_E_ARG, HFC_E_ARG.
  const hfc_server_info &info() const { return *hfc_info(get()); }
  std::string endpoint() const { return hfc_endpoint(get()); }
  int fd() const { return hfc_fd(get()); }
  int pending() const { return hfc_pending(get()); }

  // One frame, synchronously; timing may be null.
  Status filter(const hfc_request &r, hfc_timing *timing = nullptr) {
    return status(hfc_filter(get(), &r, timing));
  }
  Status submit(const hfc_request &r, std::uint32_t *id = nullptr) {
    return status(hfc_submit(get(), &r, id));
  }
  // Asks the server to drop frame id if it has not started (hfc_cancel);
  // the frame still completes through wait(), cancelled() or as usual.
  Status cancel(std::uint32_t id) { return status(hfc_cancel(get(), id)); }
  // The next completion (its own status in done.status); timeout_ms < 0:
  // the client's timeout, 0: just poll. A Status that is OK may carry a
  // completion that failed: completion() gives its code and message.
  Status wait(hfc_completion &done, int timeout_ms = -1) {
    return status(hfc_wait(get(), timeout_ms, &done));
  }
  // The frame's own outcome after wait() returned done: done.status and
  // why (hfc_last_message, which then speaks of that completion), e.g.
  //   if (hf.wait(done, 0) && !hf.completion(done)) log(hf.completion(done).what());
  Status completion(const hfc_completion &done) const { return status(done.status); }
  // What hfc_last_message says about the last call on this client.
  std::string last_message() const { return hfc_last_message(get()); }

  Status variants(std::vector<hfc_variant> &out) {
    out.resize(64);
    int n = 0;
    int rc = hfc_list_variants(get(), out.data(), static_cast<int>(out.size()), &n);
    out.resize(rc ? 0 : static_cast<std::size_t>(n < 64 ? n : 64));
    return status(rc);
  }
  Status stats(hfc_stats &out) { return status(hfc_get_stats(get(), &out)); }
#ifdef HAIRFILTER_HPP_EXCEPTIONS
  std::vector<hfc_variant> variants() {
    std::vector<hfc_variant> v;
    check(variants(v));
    return v;
  }
  std::unique_ptr<hfc_stats> stats() {
    std::unique_ptr<hfc_stats> s(new hfc_stats());
    check(stats(*s));
    return s;
  }
#endif

 private:
  friend class SharedBuffer;
  // Owns c from here: should the control block's allocation throw,
  // shared_ptr closes c before the exception leaves.
  explicit Client(hfc_client *c) : c_(c, hfc_close) {}
  Status status(int rc) const {
    return rc ? Status(rc, hfc_last_message(get())) : Status();
  }
  // Shared with nothing but the SharedBuffers' weak references, which
  // tell them whether the connection is still open.
  std::shared_ptr<hfc_client> c_;
};

// A segment of memory shared with the server (hfc_shm_alloc), freed with
// the object. It may outlive its Client: once the connection is closed,
// hfc_close has unmapped the segment (data() must not be used then), and
// the object only forgets it.
class SharedBuffer {
 public:
  SharedBuffer() : c_(), p_(nullptr), n_(0) {}
#ifdef HAIRFILTER_HPP_EXCEPTIONS
  SharedBuffer(Client &c, std::size_t bytes) : c_(), p_(nullptr), n_(0) {
    check(open(c, bytes, *this));
  }
#endif
  ~SharedBuffer() { reset(); }
  SharedBuffer(SharedBuffer &&o) noexcept : c_(std::move(o.c_)), p_(o.p_), n_(o.n_) {
    o.p_ = nullptr;
    o.n_ = 0;
  }
  SharedBuffer &operator=(SharedBuffer &&o) noexcept {
    if (this != &o) {
      reset();
      std::swap(c_, o.c_);
      std::swap(p_, o.p_);
      std::swap(n_, o.n_);
    }
    return *this;
  }
  SharedBuffer(const SharedBuffer &) = delete;
  SharedBuffer &operator=(const SharedBuffer &) = delete;

  static Status open(Client &c, std::size_t bytes, SharedBuffer &out) {
    void *p = nullptr;
    int rc = hfc_shm_alloc(c.get(), bytes, &p);
    if (rc) return Status(rc, hfc_last_message(c.get()));
    out.reset();
    out.c_ = c.c_;
    out.p_ = p;
    out.n_ = bytes;
    return Status();
  }

  void *data() const { return p_; }
  std::size_t size() const { return n_; }
  // The segment at byte_offset as T (the caller keeps it aligned for T).
  template <class T>
  T *as(std::size_t byte_offset = 0) const {
    return reinterpret_cast<T *>(static_cast<unsigned char *>(p_) + byte_offset);
  }
  void reset() {
    if (p_) {
      std::shared_ptr<hfc_client> c = c_.lock();
      if (c) hfc_shm_free(c.get(), p_);   // else hfc_close unmapped it already
    }
    c_.reset();
    p_ = nullptr;
    n_ = 0;
  }

 private:
  std::weak_ptr<hfc_client> c_;
  void *p_;
  std::size_t n_;
};

}  // namespace hairfilter

#endif  // HAIRFILTER_HPP
