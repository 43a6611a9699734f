"""A hairfilterd client in Python 3 and numpy: protocol version 4 (3, 2 or 1
with a server that speaks only those) over a Unix socket or TCP, with
shared memory.

    import numpy as np, hairfilter
    with hairfilter.Client("unix:/run/hairfilterd/hairfilterd.sock") as hf:
        done = hf.filter("Base", features)        # features: [h][w][spp*6] float32
        done.result                               # [h][w][3]: color, highlight, alpha
        done.timing.server_us

Tensors are numpy arrays, NHWC and C-contiguous, float32 or float16
(protocol/FEATURES.md). Results are received straight into their arrays; a
request whose features, result (and rgba) all lie in one segment from
Client.shared_memory() travels as a 32-byte reference, the segment's
descriptor having come over the Unix socket (SCM_RIGHTS). Like the C
library, a client is one connection, not thread-safe; several URLs separated
by commas are tried in order when connecting (the C library also fails over
mid-stream; this client does not).
"""

import array
import errno
import mmap
import os
import socket
import ssl
import time
from collections import namedtuple

import numpy as np

from . import protocol as P


# X509 verification results (x509_vfy.h) and what to check for them, as
# libhairfilter says it (client/lib/tls.c).
_NOT_SIGNED = (2, 18, 19, 20, 21)   # issuer unknown, self-signed, leaf unverifiable
_MISMATCH = (62, 64)                # host name, IP address
_VERIFY_HINTS = {10: " (the server's certificate must be renewed)",
                 9: " (check the clocks of both machines)"}
# OpenSSL's reason codes seen in a handshake, and their hints.
_REASON_HINTS = {
    "TLSV13_ALERT_CERTIFICATE_REQUIRED":
        " (the server requires a client certificate: give one with its key, tls_cert= and "
        "tls_key=)",
    "SSLV3_ALERT_HANDSHAKE_FAILURE":
        " (the server refused the handshake: does it require a client certificate?)",
    "TLSV1_ALERT_UNKNOWN_CA":
        " (the server does not trust this client certificate: is it signed by the CA of "
        "the server's --tls-client-ca?)",
    "SSLV3_ALERT_CERTIFICATE_EXPIRED": " (the server says this client certificate has expired)",
    "SSLV3_ALERT_UNSUPPORTED_CERTIFICATE":
        " (the server refused this client certificate's purpose: a client certificate needs "
        "extendedKeyUsage=clientAuth, docs/SERVER.md \"Certificates for a render farm\"; a "
        "server's certificate will not do)",
    "WRONG_VERSION_NUMBER":
        " (the server did not answer in TLS: is it a plain tcp: listener? then use a tcp: URL)",
    "UNEXPECTED_EOF_WHILE_READING":
        " (the server closed the connection during the TLS handshake: is it a plain tcp: "
        "listener? then use a tcp: URL)",
}
_REASON_HINTS["SSLV3_ALERT_BAD_CERTIFICATE"] = _REASON_HINTS["TLSV1_ALERT_UNKNOWN_CA"]
_REASON_HINTS["PACKET_LENGTH_TOO_LONG"] = _REASON_HINTS["WRONG_VERSION_NUMBER"]


def _ssl_reason(e):
    """OpenSSL's reason of e in its own words ("tlsv1 alert unknown ca"),
    with what to check for the usual ones."""
    reason = getattr(e, "reason", None)
    if not reason:
        return str(getattr(e, "strerror", None) or e)
    return reason.lower().replace("_", " ") + _REASON_HINTS.get(reason, "")


def _overlapping(offsets, arrays):
    """Whether any two of the regions (offset, array.nbytes) share a byte:
    PROTOCOL.md refuses such a reference, so the frame takes the socket."""
    spans = sorted((o, o + a.nbytes) for o, a in zip(offsets, arrays))
    return any(b0 < a1 for (_, a1), (b0, _) in zip(spans, spans[1:]))


class Error(Exception):
    """A call that failed. code is the protocol's name of the error ("BUSY",
    "UNKNOWN_VARIANT", ...) or a local one: "URL", "CONNECT", "TLS", "CLOSED",
    "TIMEOUT", "IO", "ARG", "PROTOCOL", "INFLIGHT", "NOPENDING", "UNSUPPORTED";
    "TOO_LARGE" and "UNSUPPORTED" also come from submit() for a frame over
    what the server announced (info), before anything is sent. message says
    what exactly."""

    def __init__(self, code, message):
        super().__init__("%s: %s" % (code, message) if message else code)
        self.code = code
        self.message = message


ServerInfo = namedtuple("ServerInfo", "name software_version version max_width max_height "
                                      "max_spp max_inflight max_batch queue_size auth_required "
                                      "f32 f16 shm max_frame_bytes")
ServerInfo.__doc__ = ("What the server said about itself in the handshake (HELLO_OK, "
                      "protocol/PROTOCOL.md): its name and software version, the protocol "
                      "version of the connection, its limits (max_width x max_height, max_spp, "
                      "max_frame_bytes: a frame over them is refused before it is sent), "
                      "max_inflight per connection, max_batch, queue_size, whether it wants a "
                      "token, the dtypes it takes (f32, f16) and whether the connection has "
                      "shared memory.")
Timing = namedtuple("Timing", "queue_us input_us infer_us output_us server_us total_us batch "
                              "via_shm out_of_range input_sanitised")
Timing.__doc__ = ("Microseconds: the server's parts and total (server_us), and what the caller "
                  "waited (total_us); flags as in hfc_timing.")


class Completion:
    """One request's outcome: status "OK" or an error code, message, the
    result (and rgba) arrays, timing, and the user value of submit()."""

    __slots__ = ("id", "status", "message", "result", "rgba", "timing", "user")

    def __init__(self, id_, status, message, result, rgba, timing, user):
        self.id, self.status, self.message = id_, status, message
        self.result, self.rgba, self.timing, self.user = result, rgba, timing, user

    def __repr__(self):
        return "Completion(id=%d, status=%s)" % (self.id, self.status)


_DTYPES = {np.dtype(np.float32): P.F32, np.dtype(np.float16): P.F16}


class Segment:
    """Memory shared with the server (Client.shared_memory). array() gives
    numpy views into it; requests whose tensors are all views of one segment
    go by reference. close() releases it (the client's close does too)."""

    def __init__(self, client, seg_id, mm, size):
        self._client, self.id, self._mm, self.size = client, seg_id, mm, size
        self.base = np.frombuffer(mm, dtype=np.uint8).__array_interface__["data"][0]

    def array(self, shape, dtype=np.float32, offset=0):
        """A view of shape and dtype at byte offset: a multiple of the
        element size, else the server would refuse a reference to it and a
        frame using it takes the socket. Error("ARG") for a view that would
        not lie within the segment, or a closed segment."""
        if self._mm is None:
            raise Error("ARG", "Segment.array: the segment is closed")
        dt = np.dtype(dtype)
        nbytes = int(np.prod(shape, dtype=np.int64)) * dt.itemsize
        if offset < 0 or offset + nbytes > self.size:
            raise Error("ARG", "Segment.array: %d bytes (%s of %s) at offset %d run past the "
                               "segment's %d bytes: allocate a larger one "
                               "(Client.shared_memory)"
                        % (nbytes, tuple(shape), dt, offset, self.size))
        return np.ndarray(shape, dtype=dt, buffer=self._mm, offset=offset)

    def place(self, a):
        """The byte offset of array a in this segment, or None (also for an
        array not aligned to its element size, which PROTOCOL.md refuses:
        the segment starts on a page, so its offset would not be either)."""
        if a is None or not a.flags.c_contiguous or not a.flags.aligned:
            return None
        off = a.__array_interface__["data"][0] - self.base
        if 0 <= off and off + a.nbytes <= self.size:
            return off
        return None

    def close(self):
        """Releases the segment on the server and unmaps it; a second close
        does nothing. Error("ARG") while a pending request uses it (wait()
        for its completion first): the segment then stays usable. On a
        lost connection it is unmapped all the same (the server released
        it with the connection), and the loss is raised."""
        if self._mm is None:
            return
        self._client._shm_check_unused(self)
        try:
            self._client._shm_destroy(self)
        finally:
            self._unmap()

    def _unmap(self):
        try:
            self._mm.close()
        except BufferError:
            pass   # views of it are still alive: the mapping goes with the last
        self._mm = None


class _Pending:
    __slots__ = ("id", "variant", "result", "rgba", "user", "t0", "shm", "budget")

    def __init__(self, id_, variant, result, rgba, user, shm, budget=0):
        self.id, self.variant, self.result, self.rgba = id_, variant, result, rgba
        self.user, self.t0, self.shm, self.budget = user, time.monotonic(), shm, budget


def _connect_hint(kind, e):
    """What to check after the usual connect failures (as libhairfilter says)."""
    if kind == "unix" and e.errno in (errno.EACCES, errno.EPERM):
        return (" (the socket's permissions refuse this user: is it in the server's group, "
                "e.g. hairfilter?)")
    if kind == "unix" and e.errno == errno.ENOENT:
        return " (no socket there: is hairfilterd running?)"
    if e.errno == errno.ECONNREFUSED:
        return " (nothing listens there: is hairfilterd running?)"
    if kind == "unix" and e.errno == errno.ETIMEDOUT:
        return (" (the server accepted no connection within the timeout, its queue of "
                "connections full: is hairfilterd stopped or overloaded?)")
    return ""


def _connect_unix(s, path, timeout):
    """Connects the Unix socket s within timeout seconds (None: no limit).
    A listener whose queue of connections is full (a stopped or overloaded
    server) refuses a connect at once with EAGAIN: it is tried again a few
    milliseconds apart until the timeout, then OSError ETIMEDOUT, as
    libhairfilter does."""
    deadline = None if timeout is None else time.monotonic() + timeout
    while True:
        try:
            s.connect(path)
            return
        except BlockingIOError as e:
            if e.errno != errno.EAGAIN:
                raise
        left = None if deadline is None else deadline - time.monotonic()
        if left is not None and left <= 0:
            raise OSError(errno.ETIMEDOUT, os.strerror(errno.ETIMEDOUT))
        time.sleep(0.01 if left is None else min(0.01, left))


class Client:
    """One connection to hairfilterd. url: "unix:PATH", "tcp:HOST:PORT",
    "tcp:[IPV6]:PORT", "tcp:PORT", or several separated by commas (the first
    that answers is used); "tls:HOST:PORT" (and tls:[IPV6]:PORT, tls:PORT) is
    TCP with TLS through the standard ssl module: the server's certificate
    must chain to tls_ca (a PEM file; None: the system's CAs) and name HOST
    (or tls_server_name); tls_cert and tls_key are a client certificate for
    mutual TLS, given together. timeout: seconds per blocking step (None:
    none). Raises Error with, as libhairfilter, the code of the last
    endpoint tried ("CONNECT", "TLS", or the handshake's error:
    "UNAUTHORIZED", "VERSION", "BUSY", ...) and the reason of every
    endpoint (a refused certificate says why and what to check), or "ARG"
    before connecting for TLS files that cannot be used (naming tls_ca,
    tls_cert or tls_key) or for TLS options with no tls: endpoint (the
    connection would be plain, its token unencrypted)."""

    def __init__(self, url, client_name="hairfilter-python", token=None, timeout=30.0,
                 tls_ca=None, tls_cert=None, tls_key=None, tls_server_name=None):
        self.timeout = timeout
        self._tls = (tls_ca, tls_cert, tls_key, tls_server_name)
        self._sock = None
        self._pending = {}
        self._done = []
        self._next_id = 1
        self._segments = []
        self._variants = None
        self._fds = []
        self._broken = None
        self._lost = set()   # ids of the completions _fail made
        addrs = []
        for ep in url.split(","):
            try:
                addrs.append((ep, P.parse_url(ep)))
            except ValueError as e:
                raise Error("URL", str(e))
        self._ssl = None
        if any(a.kind == "tls" for _, a in addrs):
            self._ssl = self._tls_context(check_hostname=True)
        elif tls_ca or tls_cert or tls_key or tls_server_name:
            # As libhairfilter: ignored, they would leave the connection
            # plain, its token and frames unencrypted.
            raise Error("ARG", "tls_ca, tls_cert, tls_key and tls_server_name are for tls: "
                        "endpoints, and %s has none: the connection would be plain, its token "
                        "and frames unencrypted; connect to tls:HOST:PORT, or leave the TLS "
                        "options unset" % url)
        # As libhairfilter: the code is the last endpoint's, the message
        # every endpoint's reason.
        code, reasons = "URL", []
        for ep, addr in addrs:
            try:
                self._open(addr, client_name, token or "")
                self.endpoint = ep
                return
            except Error as e:
                code = e.code
                reasons.append("%s: %s" % (ep, e))
                self._close_socket()
        raise Error(code, "; ".join(reasons))

    # ---- connection ---------------------------------------------------------------

    def _open(self, addr, client_name, token):
        self._broken = None   # what an endpoint tried before left
        try:
            if addr.kind == "unix":
                s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
                s.settimeout(self.timeout)
                try:
                    _connect_unix(s, addr.path, self.timeout)
                except OSError:
                    s.close()
                    raise
            else:
                s = socket.create_connection((addr.host, addr.port), timeout=self.timeout)
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        except OSError as e:
            raise Error("CONNECT", "connect: %s%s" % (e.strerror or e, _connect_hint(addr.kind, e)))
        if addr.kind == "tls":
            s = self._wrap_tls(s, addr)
        self._sock = s
        self._unix = addr.kind == "unix"
        hello = P.encode_hello(client_name, token)
        refused = None
        if addr.kind == "tls":
            self._send(hello)
        else:
            try:
                s.sendall(hello)
            except socket.timeout:
                self._fail("TIMEOUT", "sending took longer than the timeout")
            except OSError as e:
                # A server refusing the connection outright (a fatal BUSY at
                # --max-connections) writes its ERROR and closes before it
                # reads the HELLO, so the send fails with the reason unread:
                # read it, and report the send's failure only without one.
                try:
                    refused = self._read_header(self.timeout)
                    refused += (self._read_payload(refused[2]),)
                except Error:
                    refused = None
                if refused is None or refused[0] != P.ERROR:
                    self._fail("CLOSED" if isinstance(e, (BrokenPipeError, ConnectionResetError))
                               else "IO", "send: %s" % (e.strerror or e))
        if refused is not None:
            type_, _, length, payload = refused
        else:
            type_, _, length = self._read_header(self.timeout)
            payload = self._read_payload(length)
        if type_ == P.ERROR:
            code, _, msg = P.decode_error(payload)
            if code == P.E_UNAUTHORIZED:
                msg += ("; give the server's token: Client(url, token=...)" if not token else
                        "; the token given is not the server's (its --auth-token-file)")
            raise Error(P.code_name(code), msg)
        if type_ != P.HELLO_OK:
            raise Error("PROTOCOL", "handshake answered with message type %d" % type_)
        ok = P.decode_hello_ok(payload)
        self.info = ServerInfo(ok.server_name, ok.software_version, ok.version, ok.max_width,
                               ok.max_height, ok.max_spp, ok.max_inflight, ok.max_batch,
                               ok.queue_size, bool(ok.server_flags & P.SERVER_AUTH_REQUIRED),
                               bool(ok.dtypes & 1), bool(ok.dtypes & 2),
                               bool(ok.server_flags & P.SERVER_SHM), ok.max_frame_bytes)

    def _tls_context(self, check_hostname):
        """The ssl context of the TLS arguments (TLS 1.2 at least), each file
        checked on its own so that a bad one is named: Error("ARG")."""
        ca, cert, key, _ = self._tls
        if bool(cert) != bool(key):
            raise Error("ARG", "give tls_cert and tls_key together (tls_cert %s, tls_key %s): "
                               "a client certificate goes with its private key" % (cert, key))
        for what, path, marker in (("tls_ca", ca, b"CERTIFICATE-----"),
                                   ("tls_cert", cert, b"CERTIFICATE-----"),
                                   ("tls_key", key, b"PRIVATE KEY-----")):
            if path is None:
                continue
            try:
                with open(path, "rb") as fh:
                    text = fh.read()
            except OSError as e:
                raise Error("ARG", "%s %s: %s" % (what, path, e.strerror or e))
            if marker not in text:
                raise Error("ARG", "%s %s: no PEM %s in the file" % (what, path, marker[:-5]
                                                                     .decode().lower()))
        try:
            ctx = ssl.create_default_context(cafile=ca)
        except (OSError, ssl.SSLError) as e:
            raise Error("ARG", "tls_ca %s: %s" % (ca or "(the system's CA store)",
                                                   _ssl_reason(e)))
        ctx.minimum_version = ssl.TLSVersion.TLSv1_2
        ctx.check_hostname = check_hostname
        if cert:
            try:
                ctx.load_cert_chain(cert, key)
            except (OSError, ssl.SSLError) as e:
                # A certificate that parses (as a CA list) leaves the key at fault.
                try:
                    ssl.create_default_context(cafile=cert)
                except (OSError, ssl.SSLError):
                    raise Error("ARG", "tls_cert %s: %s" % (cert, _ssl_reason(e)))
                if getattr(e, "reason", None) == "KEY_VALUES_MISMATCH":
                    raise Error("ARG", "tls_key %s is not the private key of tls_cert %s"
                                % (key, cert))
                raise Error("ARG", "tls_key %s: %s" % (key, _ssl_reason(e)))
        return ctx

    def _wrap_tls(self, s, addr):
        """The TLS session on the connected socket s, the certificate and the
        host name checked. A refusal says why, in libhairfilter's words."""
        ca, cert, key, name = self._tls
        try:
            return self._ssl.wrap_socket(s, server_hostname=name or addr.host)
        except ssl.SSLCertVerificationError as e:
            s.close()
            msg = "TLS handshake: server certificate refused: %s" % e.verify_message
            if e.verify_code in _NOT_SIGNED:
                msg += (" (the server's certificate is not signed by a CA of tls_ca %s)" % ca
                        if ca else " (the server's certificate is not signed by a CA of the "
                        "system's CA store, used as no tls_ca was given: pass tls_ca=, the "
                        "PEM file of the CA that signed it)")
            elif e.verify_code in _MISMATCH:
                names = self._peer_names(addr, name or addr.host)
                msg += (" (the certificate names %s: connect with one of them, or set "
                        "tls_server_name)" % ", ".join(names) if names else
                        " (the certificate does not name the URL's host: connect with a name "
                        "in its subjectAltName, or set tls_server_name)")
            elif e.verify_code in _VERIFY_HINTS:
                msg += _VERIFY_HINTS[e.verify_code]
            raise Error("TLS", msg)
        except (ssl.SSLError, OSError) as e:
            s.close()
            if isinstance(e, socket.timeout):
                raise Error("TIMEOUT", "TLS handshake: no answer within the timeout")
            raise Error("TLS", "TLS handshake: %s" % _ssl_reason(e))

    def _peer_names(self, addr, sni):
        """The DNS and IP names of the server's certificate, had from a second
        handshake that checks the chain but not the host name; [] when that
        fails too."""
        try:
            ctx = self._tls_context(check_hostname=False)
            with socket.create_connection((addr.host, addr.port),
                                          timeout=min(self.timeout or 5, 5)) as raw:
                with ctx.wrap_socket(raw, server_hostname=sni) as t:
                    cert = t.getpeercert()
        except (Error, OSError):
            return []
        return ["%s:%s" % ("IP" if k == "IP Address" else k, v)
                for k, v in cert.get("subjectAltName", ()) if k in ("DNS", "IP Address")]

    def _close_socket(self):
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def close(self):
        """Releases the segments and closes; pending requests are abandoned
        (first, so that their segments can be released). A connection
        already lost raises nothing here: the segments are unmapped, the
        socket closed."""
        self._pending.clear()
        for seg in list(self._segments):
            try:
                seg.close()
            except Error:
                pass   # the connection is lost, and its segments with it (unmapped here)
        self._close_socket()
        for fd in self._fds:
            os.close(fd)
        self._fds = []

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _fail(self, code, message):
        """The connection is unusable: every later call raises this, once
        wait() has returned the frames that were pending, each completed
        with it (as libhairfilter completes them), so that a loop on
        pending ends and says to connect again."""
        hint = "; connect again (a new Client)"
        self._broken = Error(code, message if message.endswith(hint) else message + hint)
        self._close_socket()
        now = time.monotonic()
        for rid, p in sorted(self._pending.items()):
            t = Timing(0, 0, 0, 0, 0, (now - p.t0) * 1e6, 0, False, False, False)
            self._done.append(Completion(rid, code, "the connection was lost (%s)%s"
                                         % (message, hint), None, None, t, p.user))
            self._lost.add(rid)
        self._pending.clear()
        raise self._broken

    def _check(self):
        if self._broken is not None:
            raise self._broken
        if self._sock is None:
            raise Error("CLOSED", "the client is closed")

    # ---- bytes in and out -------------------------------------------------------

    def _send(self, *parts):
        try:
            for p in parts:
                self._sock.sendall(p)
        except socket.timeout:
            self._fail("TIMEOUT", "sending took longer than the timeout")
        except ssl.SSLError as e:
            self._fail("TLS", "TLS write: %s" % _ssl_reason(e))
        except OSError as e:
            closed = isinstance(e, (BrokenPipeError, ConnectionResetError))
            if closed:
                self._read_left()
            self._fail("CLOSED" if closed else "IO", "send: %s" % (e.strerror or e))

    def _read_left(self):
        """A write failed because the server closed. It answers a frame from
        its header and may close while it is still being written: after a
        fatal ERROR for it (TOO_LARGE over max_frame_bytes), or at the end of
        a drain, whose last reply may be the SHUTTING_DOWN of that very frame
        (PROTOCOL.md, "Fatal or not"). Those replies wait on a plain socket
        (a Unix socket keeps them; over TCP they are there unless a reset
        threw them away): read them, so each frame completes as the server
        answered it. A fatal ERROR among them is raised as the loss."""
        if isinstance(self._sock, ssl.SSLSocket):
            return
        try:
            while self._broken is None:
                self._read_one(0)
        except Error:
            pass
        if self._broken is not None and self._broken.code != "CLOSED":
            raise self._broken

    def _recv_into(self, view, first_timeout=None):
        """Fills the writable memoryview. The first byte may take
        first_timeout seconds (None: the client's timeout, and running out
        of it ends the connection; 0: what is there now), the rest the
        client's timeout. Descriptors that come along (SHM_CREATED's) are
        kept in self._fds."""
        got = 0
        self._sock.settimeout(self.timeout if first_timeout is None else first_timeout)
        try:
            while got < len(view):
                if self._unix:
                    n, anc, _, _ = self._sock.recvmsg_into([view[got:]],
                                                           socket.CMSG_SPACE(4 * 4))
                else:
                    # SSL sockets have no recvmsg; nothing but bytes comes over TCP.
                    n, anc = self._sock.recv_into(view[got:]), ()
                for level, type_, data in anc:
                    if level == socket.SOL_SOCKET and type_ == socket.SCM_RIGHTS:
                        fds = array.array("i")
                        fds.frombytes(data[:len(data) - len(data) % fds.itemsize])
                        self._fds.extend(fds)
                if n == 0:
                    self._fail("CLOSED", "the server closed the connection")
                if got == 0:
                    self._sock.settimeout(self.timeout)
                got += n
        except (socket.timeout, BlockingIOError):
            if got == 0 and first_timeout is not None:
                raise Error("TIMEOUT", "no reply within %.3f s" % first_timeout)
            self._fail("TIMEOUT", "no reply within the timeout")
        except ssl.SSLError as e:
            # Under TLS 1.3 a refused client certificate is heard here.
            self._fail("TLS", "TLS read: %s" % _ssl_reason(e))
        except OSError as e:
            self._fail("CLOSED" if isinstance(e, ConnectionResetError) else "IO",
                       "receive: %s" % (e.strerror or e))
        finally:
            if self._sock is not None:
                self._sock.settimeout(self.timeout)

    def _read_header(self, first_timeout):
        b = bytearray(P.HEADER_SIZE)
        self._recv_into(memoryview(b), first_timeout)
        try:
            return P.decode_header(bytes(b))
        except P.ProtocolError as e:
            self._fail("PROTOCOL", str(e))

    def _read_payload(self, length):
        if length > 64 << 10:
            self._fail("PROTOCOL", "a reply of %d bytes" % length)
        b = bytearray(length)
        self._recv_into(memoryview(b))
        return bytes(b)

    # ---- control requests ------------------------------------------------------------

    def _control(self, frame_bytes, reply_type):
        """Sends a control request; results that arrive meanwhile are kept."""
        self._check()
        self._send(frame_bytes)
        while True:
            got = self._read_one(self.timeout, want=reply_type)
            if got is not None:
                return got

    def variants(self):
        """The loaded variants (protocol.Variant: name, backend, precision,
        spp, levels, ranges)."""
        payload = self._control(P.frame(P.LIST_VARIANTS), P.VARIANTS)
        self._variants = P.decode_variants(payload)
        return list(self._variants)

    def stats(self):
        """The server's counters (protocol.Stats)."""
        return P.decode_stats(self._control(P.frame(P.STATS), P.STATS_REPLY))

    def shared_memory(self, nbytes):
        """A segment of nbytes shared with the server (Unix sockets)."""
        self._check()
        if not self.info.shm:
            raise Error("UNSUPPORTED", "%s offers no shared memory" % self.endpoint)
        for fd in self._fds:
            os.close(fd)
        self._fds = []
        seg_id, size = P.decode_shm_created(self._control(P.encode_shm_create(nbytes),
                                                          P.SHM_CREATED))
        if size != nbytes or not self._fds:
            self._fail("PROTOCOL", "SHM_CREATED without its descriptor or of another size")
        fd = self._fds.pop(0)
        try:
            mm = mmap.mmap(fd, nbytes, mmap.MAP_SHARED, mmap.PROT_READ | mmap.PROT_WRITE)
        finally:
            os.close(fd)
        seg = Segment(self, seg_id, mm, nbytes)
        self._segments.append(seg)
        return seg

    def _shm_check_unused(self, seg):
        # Refused before anything changes: a segment dropped from the list
        # would send its later frames through the socket without a word.
        if any(p.shm is seg for p in self._pending.values()):
            raise Error("ARG", "a request pending on this segment still uses it: wait() for "
                               "its completion, then close the segment")

    def _shm_destroy(self, seg):
        self._shm_check_unused(seg)
        if seg in self._segments:
            self._segments.remove(seg)
        if self._sock is not None and self._broken is None:
            self._send(P.encode_shm_destroy(seg.id))

    # ---- filtering -------------------------------------------------------------------

    def _variant_name(self, name):
        """The loaded variant name means: itself, or the one it matches
        without regard to case (as libhairfilter matches). A name still
        unknown is sent as it is: the server answers UNKNOWN_VARIANT for
        that frame (and counts it), and the completion's message adds the
        names listed here."""
        for attempt in range(2):
            if self._variants is None or attempt:
                self.variants()
            names = [v.name for v in self._variants]
            if name in names:
                return name
            close = [n for n in names if n.lower() == name.lower()]
            if len(close) == 1:
                return close[0]
        return name

    def _check_variant(self, name, spp, given):
        """Raises ARG, in this API's words, for a frame whose samples per
        pixel or estimate the listed variant does not match (the server
        would answer INVALID after the whole upload, naming the wire's
        fields); the variants are listed again first, since a reload may
        have changed what the name serves. A name not listed passes."""
        for attempt in range(2):
            v = next((v for v in self._variants or () if v.name == name), None)
            if v is None or (v.spp == spp and bool(v.estimate) == given):
                return
            if not attempt:
                self.variants()
        if v.spp != spp:
            raise Error("ARG", "features: %d samples per pixel (%d channels), variant %s takes "
                               "%d (Variant.spp): render %d, or name a variant of %d spp "
                               "(variants())" % (spp, spp * P.FEATURES, name, v.spp, v.spp, spp))
        if given:
            raise Error("ARG", "variant %s reads no estimate: call without estimate=" % name)
        raise Error("ARG", "variant %s reads stochastic transparency's alpha-corrected estimate "
                           "(Variant.estimate): pass it as estimate=, [height][width][3] of the "
                           "features' dtype (protocol/FEATURES.md)" % name)

    def _check_limits(self, w, h, spp, in_dtype, out_dtype, by_reference, payload):
        """Raises, before anything is sent, for a frame over what the server
        announced in HELLO_OK (self.info): TOO_LARGE over max_width x
        max_height, or, through the socket, over max_frame_bytes (which the
        server would answer only after the whole upload, closing the
        connection); UNSUPPORTED for a dtype it does not take. The
        connection stays usable."""
        i = self.info
        if w > i.max_width or h > i.max_height:
            raise Error("TOO_LARGE", "a %dx%d frame is over the limit of %dx%d that %s announced "
                                     "(info.max_width, max_height; hairfilterd's --max-size): "
                                     "nothing was sent; filter it in tiles within the limit, or "
                                     "have the server take larger frames: its --max-size, or, "
                                     "where its log says 'max size lowered', the "
                                     "--max-memory-mb or --max-frame-mb that lowered it"
                        % (w, h, i.max_width, i.max_height, self.endpoint))
        offered = {np.dtype(np.float32): i.f32, np.dtype(np.float16): i.f16}
        for what, dt in (("features", in_dtype), ("out_dtype", out_dtype)):
            if not offered[dt]:
                raise Error("UNSUPPORTED", "%s: %s takes %s tensors only (info.f32, info.f16): "
                                           "nothing was sent"
                            % (what, self.endpoint, "float16" if i.f16 else "float32"))
        if not by_reference and payload > i.max_frame_bytes:
            raise Error("TOO_LARGE", "a %dx%d frame of %d spp is %d bytes on the wire, over the "
                                     "%d-byte limit that %s announced (info.max_frame_bytes; "
                                     "hairfilterd's --max-frame-mb): nothing was sent; put its "
                                     "arrays in one shared_memory() segment, send float16, or "
                                     "filter it in tiles"
                        % (w, h, spp, payload, i.max_frame_bytes, self.endpoint))

    def submit(self, variant, features, out_dtype=None, result=None, composite=False,
               rgba=None, hair=(0, 0, 0), light=(1, 1, 1), background=(0, 0, 0), user=None,
               estimate=None, deadline_us=None):
        """Sends one frame and returns its id; wait() gives its Completion.
        It does not wait for the result, but through the socket it writes
        the whole frame first (one larger than the socket's buffers waits
        while the server reads it, up to the client's timeout; through
        shared memory only a reference goes), and the first request naming
        a variant on a connection lists the server's variants (a round
        trip). features: [h][w][spp*6] float32 or
        float16, C-contiguous; hair, light, background: 3 finite numbers
        each, linear RGB, for the composite.
        estimate: the frame's alpha-corrected estimate, [h][w][3] of the
        features' dtype, for a variant that reads it (Variant.estimate;
        protocol version 3), sent after the features.
        deadline_us: the frame's budget, 1..2**32-1 microseconds from its
        arrival at the server (on the server's clock): a frame that has not
        started running when it passes is not computed, and its completion
        has status "EXPIRED" (retrying cannot help). Sent to a server of
        protocol version 4 (info.version); an older one gets the frame
        without it and computes it however late. None: no budget.
        result / rgba: arrays to receive into ([h][w][3], [h][w][4] of
        out_dtype, by default the features' dtype), made when None. The
        arrays must stay untouched until the completion."""
        self._check()
        f = features
        if not isinstance(f, np.ndarray) or f.ndim != 3 or f.dtype not in _DTYPES:
            raise Error("ARG", "features: want a [height][width][spp*6] float32 or float16 "
                               "array")
        if not f.flags.c_contiguous:
            raise Error("ARG", "features: not C-contiguous (np.ascontiguousarray)")
        h, w, ch = f.shape
        if not (1 <= h <= 65535 and 1 <= w <= 65535):
            raise Error("ARG", "features: a %dx%d frame, want 1..65535 pixels a side" % (w, h))
        if ch % P.FEATURES or not 1 <= ch // P.FEATURES <= P.MAX_SPP:
            raise Error("ARG", "features: %d channels per pixel, want spp*6 with spp 1..16" % ch)
        spp = ch // P.FEATURES
        if estimate is not None:
            if self.info.version < 3:
                raise Error("ARG", "estimate: %s speaks protocol version %d; the estimate needs 3"
                            % (self.endpoint, self.info.version))
            if (not isinstance(estimate, np.ndarray) or estimate.shape != (h, w, 3) or
                    estimate.dtype != f.dtype or not estimate.flags.c_contiguous):
                raise Error("ARG", "estimate: want a C-contiguous %s array of shape %s"
                            % (f.dtype, (h, w, 3)))
        budget = 0
        if deadline_us is not None:
            if (isinstance(deadline_us, bool) or not isinstance(deadline_us, (int, np.integer))
                    or not 1 <= deadline_us <= P.BUDGET_MAX):
                raise Error("ARG", "deadline_us: want microseconds, 1..%d, or None for no "
                                   "budget; got %r" % (P.BUDGET_MAX, deadline_us))
            # Only a version-4 server knows the flag (PROTOCOL.md, "Version 4").
            budget = int(deadline_us) if self.info.version >= 4 else 0
        odt = np.dtype(out_dtype) if out_dtype is not None else f.dtype
        if odt not in _DTYPES:
            raise Error("ARG", "out_dtype: want float32 or float16")

        def out_array(a, channels, what):
            if a is None:
                return np.empty((h, w, channels), dtype=odt)
            if a.shape != (h, w, channels) or a.dtype != odt or not a.flags.c_contiguous:
                raise Error("ARG", "%s: want a C-contiguous %s array of shape %s"
                            % (what, odt, (h, w, channels)))
            return a
        colours = {}
        for what, v in (("hair", hair), ("light", light), ("background", background)):
            try:
                c = tuple(float(x) for x in v)
            except (TypeError, ValueError):
                c = ()
            if len(c) != 3 or not all(np.isfinite(c)):
                raise Error("ARG", "%s: want 3 finite numbers (linear RGB), got %r" % (what, v))
            colours[what] = c
        result = out_array(result, P.OUTPUTS, "result")
        composite = composite or rgba is not None
        rgba = out_array(rgba, 4, "rgba") if composite else None
        name = self._variant_name(variant)
        self._check_variant(name, spp, estimate is not None)
        if len(self._pending) >= self.info.max_inflight:
            raise Error("INFLIGHT", "%d requests pending, as many as %s allows on a connection "
                                    "(info.max_inflight): collect some with wait()"
                        % (len(self._pending), self.endpoint))
        seg, ref = None, None
        arrays = [f, result] + ([rgba] if composite else [])
        for s in self._segments:
            offs = (s.place(f), s.place(result), s.place(rgba) if composite else 0)
            # By reference, the estimate must follow the features in the segment.
            if estimate is not None and (offs[0] is None or
                                         s.place(estimate) != offs[0] + f.nbytes):
                continue
            if None not in offs and not _overlapping(offs, arrays):
                seg, ref = s, (s.id,) + offs
                break
        # The payload a FILTER header would announce: its fields and name,
        # then a reference or the tensors.
        payload = P.FILTER_FIXED.size + len(name.encode("ascii")) + (
            P.SHM_REF_SIZE if ref else f.nbytes + (0 if estimate is None else estimate.nbytes)) + (4 if budget else 0)
        self._check_limits(w, h, spp, f.dtype, odt, ref is not None, payload)
        rid = self._next_id
        self._next_id = self._next_id % 0xFFFFFFFF + 1
        head = P.encode_filter_head(rid, name, w, h, spp, _DTYPES[f.dtype], _DTYPES[odt],
                                    composite, colours["hair"], colours["light"],
                                    colours["background"],
                                    shm=ref, estimate=estimate is not None, budget_us=budget)
        self._pending[rid] = _Pending(rid, name, result, rgba, user, seg, budget)
        try:
            if ref:
                self._send(head)
            elif estimate is not None:
                self._send(head, memoryview(f).cast("B"), memoryview(estimate).cast("B"))
            else:
                self._send(head, memoryview(f).cast("B"))
        except Error:
            # Answered before the server closed (_read_left): the frame's
            # completion says how; the next call raises the loss. Not
            # answered, it is this call's failure, not a completion.
            mine = next((d for d in self._done if d.id == rid), None)
            if mine is not None and rid not in self._lost:
                return rid
            if mine is not None:
                self._done.remove(mine)
            raise
        return rid

    def _read_one(self, first_timeout, want=None):
        """Reads one frame: a control reply of type want (its payload is
        returned), or a RESULT / ERROR for a request (kept as a completion)."""
        type_, rid, length = self._read_header(first_timeout)
        if type_ == P.RESULT:
            p = self._pending.get(rid)
            head = bytearray(P.RESULT_FIXED.size)
            if p is None or length < len(head):
                self._fail("PROTOCOL", "a RESULT for no request (id %d)" % rid)
            self._recv_into(memoryview(head))
            try:
                r = P.decode_result_head(bytes(head), length)
            except P.ProtocolError as e:
                self._fail("PROTOCOL", str(e))
            status = "OK" if r.status == 0 else P.code_name(r.status)
            if r.status == 0:
                shm = bool(r.flags & P.FILTER_SHM)
                if (r.width, r.height) != p.result.shape[1::-1] or shm != (p.shm is not None):
                    self._fail("PROTOCOL", "a RESULT that does not match its request")
                if not shm:
                    self._recv_into(memoryview(p.result).cast("B"))
                    if p.rgba is not None:
                        self._recv_into(memoryview(p.rgba).cast("B"))
            t = Timing(r.queue_us, r.input_us, r.infer_us, r.output_us, r.total_us,
                       (time.monotonic() - p.t0) * 1e6, r.batch, p.shm is not None,
                       bool(r.flags & P.RESULT_OUT_OF_RANGE),
                       bool(r.flags & P.RESULT_INPUT_SANITISED))
            why = ""
            if r.status == P.E_EXPIRED:
                # the budget and the wait: by how much the server was behind
                why = ("its budget of %d us (deadline_us) passed while it was queued at %s "
                       "(it waited %d us): not computed" % (p.budget, self.endpoint, r.queue_us))
            elif r.status == P.E_CANCELLED:
                why = "cancel() took it off the queue at %s: not computed" % self.endpoint
            self._done.append(Completion(rid, status, why, p.result, p.rgba, t, p.user))
            del self._pending[rid]
            return None
        payload = self._read_payload(length)
        if type_ == P.ERROR:
            code, fatal, msg = P.decode_error(payload)
            p = self._pending.pop(rid, None) if rid else None
            if p is not None:
                t = Timing(0, 0, 0, 0, 0, (time.monotonic() - p.t0) * 1e6, 0, False, False, False)
                if code == P.E_UNKNOWN_VARIANT:
                    names = [v.name for v in self._variants or ()]
                    msg = "%s: this server has %s" % (msg, ", ".join(names) or "none")
                    self._variants = None   # the server's set changed: list again
                self._done.append(Completion(rid, P.code_name(code), msg, None, None, t, p.user))
            elif want is not None and rid == 0:
                if fatal:
                    self._fail(P.code_name(code), msg)
                raise Error(P.code_name(code), msg)
            if fatal:
                self._fail(P.code_name(code), msg)
            return None
        if type_ == want:
            return payload
        self._fail("PROTOCOL", "an unexpected message (type %d)" % type_)

    def wait(self, timeout=None):
        """The next completion, in the order the server finishes them.
        timeout: seconds (None: the client's); Error("TIMEOUT") when none
        came, Error("NOPENDING") with nothing in flight. When the
        connection is lost, the frames pending complete with its error, one
        per call, and then wait() raises it (connect again)."""
        while not self._done:
            self._check()
            if not self._pending:
                raise Error("NOPENDING", "no request in flight")
            try:
                self._read_one(self.timeout if timeout is None else timeout)
            except Error:
                if not self._done:
                    raise
        return self._done.pop(0)

    def cancel(self, rid):
        """Asks the server to drop request rid (submit()'s id) if it has not
        started it (protocol version 4: CANCEL). It still completes through
        wait(), exactly once: status "CANCELLED" when the server took it
        off its queue (not computed), or as usual when it had started (a
        computation is never cut short) or answered already. Error("ARG")
        for an id not pending, Error("UNSUPPORTED") against a server of an
        older version (nothing is sent)."""
        self._check()
        if rid not in self._pending:
            if any(d.id == rid for d in self._done):
                return   # answered already: wait() returns it as it came
            raise Error("ARG", "cancel: request %r is not pending (submit()'s id; one wait() "
                               "returned is done)" % (rid,))
        if self.info.version < 4:
            raise Error("UNSUPPORTED", "cancel: %s speaks protocol version %d; cancelling needs "
                                       "version 4: request %d completes as the server answers it"
                        % (self.endpoint, self.info.version, rid))
        self._send(P.encode_cancel(rid))

    @property
    def pending(self):
        """Requests submitted and not yet returned by wait()."""
        return len(self._pending) + len(self._done)

    def filter(self, variant, features, **kw):
        """submit() and wait for that frame; raises Error unless it succeeded.
        On Error("TIMEOUT") the frame stays pending: its completion comes
        out of a later wait() if the server answers after all (pending
        counts it)."""
        rid = self.submit(variant, features, **kw)
        while True:
            for i, c in enumerate(self._done):
                if c.id == rid:
                    del self._done[i]
                    if c.status != "OK":
                        raise Error(c.status, c.message)
                    return c
            self._check()
            try:
                self._read_one(self.timeout)
            except Error:
                # A lost connection completed this frame with its error.
                if not any(c.id == rid for c in self._done):
                    raise
