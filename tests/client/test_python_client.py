#!/usr/bin/env python3
"""The Python client (client/python) against a real hairfilterd: connect,
variants, filter over the Unix socket, TCP, TLS and shared memory, pipelined
submit/wait, statistics and errors; every result equal, byte for byte, to
what the C library (tests/client/filter_raw.c) gets for the same frame.

  test_python_client.py --daemon build/hairfilterd --filter-raw build/.../filter_raw
                        --weights DIR --version 0.1.0 --work DIR
                        --make-certs build/tests/server/make_test_certs

Exit status 77 (a skip) without numpy.
"""

import argparse
import os
import shutil
import socket
import struct
import subprocess
import sys
import threading
import time
import unittest

try:
    import numpy as np
except ImportError:
    print("test_python_client: skipped: this Python has no numpy")
    sys.exit(77)

import hairfilter
from hairfilter import protocol as P

ARGS = None
BASE1 = "Base@1spp"   # weights/base_1spp.safetensors
DAEMON = None
UNIX = TCP = TLS = None
CERTS = None


def features(h, w, spp, seed, dtype=np.float32):
    """Plausible feature values: colour, highlight, alpha, depth in [0, 1),
    tangents in [-1, 1) (protocol/FEATURES.md)."""
    rng = np.random.default_rng(seed)
    f = rng.random((h, w, spp, 6), dtype=np.float32)
    f[..., 4:] = 2 * f[..., 4:] - 1
    return np.ascontiguousarray(f.reshape(h, w, spp * 6).astype(dtype))


def recv_exactly(s, n):
    b = b""
    while len(b) < n:
        c = s.recv(n - len(b))
        if not c:
            raise EOFError("closed after %d of %d bytes" % (len(b), n))
        b += c
    return b


def read_message(s):
    """One whole message (header and payload) as bytes."""
    head = recv_exactly(s, 16)
    return head + recv_exactly(s, P.decode_header(head)[2])


def recorded_handshake():
    """The session daemon's own HELLO_OK and VARIANTS messages, whole, for
    a mock server to replay."""
    raw = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    raw.settimeout(10)
    raw.connect(UNIX[len("unix:"):])
    raw.sendall(P.encode_hello("recorder"))
    hello_ok = read_message(raw)
    raw.sendall(P.frame(P.LIST_VARIANTS))
    variants = read_message(raw)
    raw.close()
    return hello_ok, variants


def unix_listener(name, backlog):
    """A listening Unix socket at ARGS.work/name (one left there before is
    removed): (path, socket)."""
    path = os.path.join(ARGS.work, name)
    if os.path.exists(path):
        os.unlink(path)
    lsock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    lsock.bind(path)
    lsock.listen(backlog)
    return path, lsock


def c_filter(url, variant, f, shm=False, rgba=False, ca=None, estimate=None):
    """The C library's result (and composite) of frame f (and its estimate),
    as bytes."""
    h, w, ch = f.shape
    dt = "f16" if f.dtype == np.float16 else "f32"
    src = os.path.join(ARGS.work, "in.raw")
    dst = os.path.join(ARGS.work, "out.raw")
    drgba = os.path.join(ARGS.work, "rgba.raw")
    with open(src, "wb") as fh:
        fh.write(f.tobytes())
        if estimate is not None:
            fh.write(estimate.tobytes())
    cmd = [ARGS.filter_raw, url, variant, str(w), str(h), str(ch // 6), dt, src, dst]
    if estimate is not None:
        cmd.append("estimate")
    if shm:
        cmd.append("shm")
    if rgba:
        cmd += ["rgba", drgba]
    if ca:
        cmd += ["ca", ca]
    subprocess.run(cmd, check=True)
    with open(dst, "rb") as fh:
        out = fh.read()
    if rgba:
        with open(drgba, "rb") as fh:
            return out, fh.read()
    return out


def start_daemon(name, args, env=None):
    """hairfilterd with args and a ready file: the process and its URLs."""
    ready = os.path.join(ARGS.work, name + ".ready")
    if os.path.exists(ready):
        os.unlink(ready)
    with open(os.path.join(ARGS.work, name + ".log"), "w") as log:
        proc = subprocess.Popen([ARGS.daemon] + args + ["--backend", "cpu-ref", "--ready-file",
                                                        ready], stdout=log, stderr=log, env=env)
    for _ in range(3000):
        if os.path.exists(ready):
            with open(ready) as fh:
                return proc, fh.read().split()
        if proc.poll() is not None:
            break
        time.sleep(0.01)
    raise RuntimeError("hairfilterd did not start: see %s/%s.log" % (ARGS.work, name))


def tls_localhost(urls):
    """The tls: URL of urls as tls:localhost:PORT (the certificate names
    localhost only)."""
    return "tls:localhost:" + [u for u in urls if u.startswith("tls:")][0].rsplit(":", 1)[1]


def setUpModule():
    global DAEMON, UNIX, TCP, TLS, CERTS
    os.makedirs(ARGS.work, exist_ok=True)
    CERTS = os.path.join(ARGS.work, "certs")
    os.makedirs(CERTS, exist_ok=True)
    subprocess.run([ARGS.make_certs, CERTS], check=True)
    sock = os.path.join(ARGS.work, "d.sock")
    if os.path.exists(sock):
        os.unlink(sock)
    DAEMON, urls = start_daemon("daemon", [
        "--listen", "unix:" + sock, "--listen", "tcp:127.0.0.1:0", "--no-auth",
        "--listen", "tls:127.0.0.1:0", "--tls-cert", os.path.join(CERTS, "server.pem"),
        "--tls-key", os.path.join(CERTS, "server.key"),
        "--weights", os.path.join(ARGS.weights, "small.safetensors"),
        "--weights", os.path.join(ARGS.weights, "base_1spp.safetensors")])
    UNIX = [u for u in urls if u.startswith("unix:")][0]
    TCP = [u for u in urls if u.startswith("tcp:")][0]
    TLS = tls_localhost(urls)


def tearDownModule():
    DAEMON.terminate()
    if DAEMON.wait(timeout=30) != 0:
        raise RuntimeError("hairfilterd exited with %d" % DAEMON.returncode)


class PythonClient(unittest.TestCase):
    def test_handshake_and_variants(self):
        with hairfilter.Client(UNIX, client_name="py-test") as hf:
            self.assertEqual(hf.info.version, 4)
            self.assertEqual(hf.info.software_version, ARGS.version)
            self.assertEqual(hairfilter.__version__, ARGS.version)
            self.assertTrue(hf.info.shm)
            vs = {v.name: v for v in hf.variants()}
            self.assertEqual(sorted(vs), [BASE1, "Small"])
            self.assertEqual(vs["Small"].spp, 4)
            self.assertEqual(vs[BASE1].spp, 1)
            self.assertEqual(vs["Small"].levels, (16, 32, 64))
            self.assertEqual(vs["Small"].backend, "cpu-ref")
        with hairfilter.Client(TCP) as hf:
            self.assertFalse(hf.info.shm)

    def test_estimate_equals_c(self):
        """A variant that reads the alpha-corrected estimate (KernelAC,
        protocol version 3): Variant.estimate says so, the frame with its
        estimate gives the C library's bytes over the socket and shared
        memory, and a frame without it or with an estimate of the wrong
        shape is refused before anything is sent."""
        sock = os.path.join(ARGS.work, "ac.sock")
        if os.path.exists(sock):
            os.unlink(sock)
        proc, urls = start_daemon("ac", ["--listen", "unix:" + sock, "--weights",
                                         os.path.join(ARGS.weights, "kernel_ac.safetensors"),
                                         "--max-size", "64x64"])
        try:
            url = urls[0]
            f = features(20, 28, 4, 5)
            rng = np.random.default_rng(6)
            e = rng.random((20, 28, 3), dtype=np.float32)
            e[:, :4] = 0
            want = c_filter(url, "KernelAC", f, estimate=e)
            with hairfilter.Client(url) as hf:
                self.assertEqual(hf.info.version, 4)
                self.assertTrue(hf.variants()[0].estimate)
                done = hf.filter("KernelAC", f, estimate=e)
                self.assertEqual(done.status, "OK", done.message)
                self.assertEqual(done.result.tobytes(), want)
                seg = hf.shared_memory(f.nbytes + e.nbytes + 20 * 28 * 3 * 4)
                fs = seg.array(f.shape, np.float32, 0)
                es = seg.array(e.shape, np.float32, f.nbytes)    # right after the features
                rs = seg.array((20, 28, 3), np.float32, f.nbytes + e.nbytes)
                fs[...], es[...] = f, e
                done = hf.filter("KernelAC", fs, estimate=es, result=rs)
                self.assertTrue(done.timing.via_shm)
                self.assertEqual(done.result.tobytes(), want)
                with self.assertRaises(hairfilter.Error) as err:
                    hf.filter("KernelAC", f)
                self.assertEqual(err.exception.code, "ARG")   # before anything is sent
                self.assertIn("pass it as estimate=", err.exception.message)
                with self.assertRaises(hairfilter.Error) as err:
                    hf.submit("KernelAC", f, estimate=e[:, :, :2].copy())
                self.assertEqual(err.exception.code, "ARG")
        finally:
            proc.terminate()
            self.assertEqual(proc.wait(timeout=30), 0)

    def test_socket_equals_c(self):
        f = features(24, 40, 4, 1)
        want = c_filter(UNIX, "Small", f)
        with hairfilter.Client(UNIX) as hf:
            done = hf.filter("Small", f)
            self.assertEqual(done.status, "OK")
            self.assertEqual(done.result.shape, (24, 40, 3))
            self.assertEqual(done.result.dtype, np.float32)
            self.assertEqual(done.result.tobytes(), want)
            self.assertFalse(done.timing.via_shm)
            t = done.timing
            self.assertLessEqual(t.queue_us + t.input_us + t.infer_us + t.output_us, t.server_us)
            self.assertGreater(t.total_us, 0)
        with hairfilter.Client(TCP) as hf:
            self.assertEqual(hf.filter("Small", f).result.tobytes(), want)
        ca = os.path.join(CERTS, "ca.pem")
        with hairfilter.Client(TLS, tls_ca=ca) as hf:
            self.assertEqual(hf.filter("Small", f).result.tobytes(), want)
        self.assertEqual(c_filter(TLS, "Small", f, ca=ca), want)

    def refused(self, code, says, *args, **kw):
        """Client(*args, **kw) raises Error(code) whose message has each of says."""
        with self.assertRaises(hairfilter.Error) as e:
            hairfilter.Client(*args, **kw)
        self.assertEqual(e.exception.code, code, str(e.exception))
        for words in says:
            self.assertIn(words, e.exception.message)
        return e.exception

    def test_tls_refusals(self):
        """A CA that did not sign the server's certificate (a file, or the
        system's store), a host name or address it does not carry, a plain
        client on the TLS port, a TLS client on the plain one: each named,
        with the handshake's code (also after another endpoint failed)."""
        other = os.path.join(CERTS, "other-ca.pem")
        ca = os.path.join(CERTS, "ca.pem")
        self.refused("TLS", ["unable to get local issuer certificate",
                             "not signed by a CA of tls_ca " + other], TLS, tls_ca=other)
        self.refused("TLS", ["system's CA store", "tls_ca="], TLS)
        missing = "unix:" + os.path.join(ARGS.work, "missing.sock")
        e = self.refused("TLS", ["No such file", "not signed by a CA"], missing + "," + TLS,
                         tls_ca=other)
        self.assertEqual(e.message.count("TLS handshake"), 1)
        self.refused("TLS", ["Hostname mismatch", "names DNS:localhost", "tls_server_name"],
                     TLS, tls_ca=ca, tls_server_name="render-99.farm")
        self.refused("TLS", ["IP address mismatch", "names DNS:localhost"],
                     "tls:127.0.0.1:" + TLS.rsplit(":", 1)[1], tls_ca=ca)
        self.refused("PROTOCOL", ["this listener speaks TLS"], "tcp:" + TLS[4:])
        self.refused("TLS", ["plain tcp: listener"], "tls:" + TCP[4:], tls_ca=ca,
                     tls_server_name="localhost")
        with hairfilter.Client(TLS, tls_ca=ca) as hf:
            self.assertEqual(hf.filter("Small", features(8, 8, 4, 3)).status, "OK")

    def test_tls_files(self):
        """TLS files that cannot be used are named before connecting."""
        ca = os.path.join(CERTS, "ca.pem")
        cert, key = os.path.join(CERTS, "client.pem"), os.path.join(CERTS, "client.key")
        other_key = os.path.join(CERTS, "client-other.key")
        self.refused("ARG", ["tls_ca /nonexistent.pem", "No such file"], TLS,
                     tls_ca="/nonexistent.pem")
        self.refused("ARG", ["tls_ca " + key, "no PEM certificate"], TLS, tls_ca=key)
        self.refused("ARG", ["give tls_cert and tls_key together"], TLS, tls_ca=ca,
                     tls_cert=cert)
        self.refused("ARG", ["give tls_cert and tls_key together"], TLS, tls_ca=ca,
                     tls_key=key)
        self.refused("ARG", ["tls_cert " + key], TLS, tls_ca=ca, tls_cert=key, tls_key=key)
        self.refused("ARG", ["tls_key " + cert, "no PEM private key"], TLS, tls_ca=ca,
                     tls_cert=cert, tls_key=cert)
        self.refused("ARG", ["tls_key %s is not the private key of tls_cert" % other_key],
                     TLS, tls_ca=ca, tls_cert=cert, tls_key=other_key)
        # With no tls: endpoint the connection would be plain, the token
        # unencrypted: refused before connecting.
        plain = "tcp:" + TLS[4:] + ",unix:/nonexistent.sock"
        self.refused("ARG", ["are for tls: endpoints", "unencrypted"], plain, tls_ca=ca)
        self.refused("ARG", ["are for tls: endpoints"], plain, tls_server_name="localhost")

    def test_mutual_tls(self):
        """Under mutual TLS: a client certificate serves without a token; none,
        or one from another CA, is refused with the server's reason; a plain
        client without the token gets the handshake's UNAUTHORIZED."""
        c = lambda name: os.path.join(CERTS, name)
        env = dict(os.environ, HAIRFILTERD_TOKEN="py-mutual-token")
        proc, urls = start_daemon("mutual", [
            "--listen", "tls:127.0.0.1:0", "--listen", "tcp:127.0.0.1:0",
            "--tls-cert", c("server.pem"), "--tls-key", c("server.key"),
            "--tls-client-ca", c("ca.pem"), "--tls-client-cert-auth",
            "--weights", os.path.join(ARGS.weights, "small.safetensors")], env)
        try:
            tls = tls_localhost(urls)
            tcp = [u for u in urls if u.startswith("tcp:")][0]
            with hairfilter.Client(tls, tls_ca=c("ca.pem"), tls_cert=c("client.pem"),
                                   tls_key=c("client.key")) as hf:
                self.assertEqual(hf.filter("Small", features(8, 8, 4, 6)).status, "OK")
            self.refused("TLS", ["certificate required", "requires a client certificate",
                                 "tls_cert="], tls, tls_ca=c("ca.pem"))
            self.refused("TLS", ["unknown ca", "does not trust this client certificate"], tls,
                         tls_ca=c("ca.pem"), tls_cert=c("client-other.pem"),
                         tls_key=c("client-other.key"))
            # A server's certificate (serverAuth) as the client's: its purpose named.
            self.refused("TLS", ["unsupported certificate", "extendedKeyUsage=clientAuth"], tls,
                         tls_ca=c("ca.pem"), tls_cert=c("server.pem"), tls_key=c("server.key"))
            self.refused("UNAUTHORIZED", [tcp, "Client(url, token=...)"], tcp)
            self.refused("UNAUTHORIZED", ["not the server's"], tcp, token="wrong-token")
            self.refused("UNAUTHORIZED", ["No such file", "is hairfilterd running?"],
                         "unix:" + os.path.join(ARGS.work, "missing.sock") + "," + tcp)
        finally:
            proc.terminate()
            proc.wait(timeout=30)
        with open(os.path.join(ARGS.work, "mutual.log")) as fh:
            log = fh.read()
        self.assertIn("the client sent no certificate", log)
        self.assertIn("this server refused the client's certificate", log)

    def test_f16_and_composite_equal_c(self):
        f = features(17, 23, 1, 2, np.float16)
        want = c_filter(UNIX, BASE1, f)
        with hairfilter.Client(UNIX) as hf:
            done = hf.filter(BASE1, f)
            self.assertEqual(done.result.dtype, np.float16)
            self.assertEqual(done.result.tobytes(), want)
        f = features(12, 9, 4, 3)
        want, want_rgba = c_filter(UNIX, "Small", f, rgba=True)
        with hairfilter.Client(UNIX) as hf:
            done = hf.filter("Small", f, composite=True, hair=(0.45, 0.25, 0.12),
                             light=(1, 1, 1), background=(0.18, 0.2, 0.24))
            self.assertEqual(done.result.tobytes(), want)
            self.assertEqual(done.rgba.shape, (12, 9, 4))
            self.assertEqual(done.rgba.tobytes(), want_rgba)

    def test_shared_memory_equals_c(self):
        f = features(32, 32, 4, 4)
        want = c_filter(UNIX, "Small", f)
        self.assertEqual(c_filter(UNIX, "Small", f, shm=True), want)
        with hairfilter.Client(UNIX) as hf:
            seg = hf.shared_memory(f.nbytes + 32 * 32 * 3 * 4 + 64)
            fin = seg.array(f.shape, np.float32, 0)
            fin[...] = f
            out = seg.array((32, 32, 3), np.float32, f.nbytes)
            done = hf.filter("Small", fin, result=out)
            self.assertTrue(done.timing.via_shm)
            self.assertEqual(out.tobytes(), want)
            # A result outside the segment: the socket path, the same bytes.
            done = hf.filter("Small", fin)
            self.assertFalse(done.timing.via_shm)
            self.assertEqual(done.result.tobytes(), want)
            # A result over its own features: regions may not overlap, so
            # the socket path, and the result is the features'.
            over = seg.array((32, 32, 3), np.float32, 0)
            done = hf.filter("Small", fin, result=over)
            self.assertFalse(done.timing.via_shm)
            self.assertEqual(over.tobytes(), want)
            fin[...] = f
            # A result at an odd byte offset (not aligned to float32): the
            # server would refuse the reference, so the socket path.
            odd = seg.array((32, 32, 3), np.float32, f.nbytes + 2)
            self.assertFalse(odd.flags.aligned)
            done = hf.filter("Small", fin, result=odd)
            self.assertFalse(done.timing.via_shm)
            self.assertEqual(odd.tobytes(), want)
            seg.close()
            # The connection is fine after the segment is gone.
            self.assertEqual(hf.filter("Small", f).result.tobytes(), want)

    def test_pipelined(self):
        frames = [features(20, 16, 4, 10 + i) for i in range(8)]
        with hairfilter.Client(UNIX) as hf:
            singles = [hf.filter("Small", f).result.tobytes() for f in frames]
            before = {v.name: v.requests_ok for v in hf.stats().variants}
            ids = {}
            for i, f in enumerate(frames):
                ids[hf.submit("Small", f, user=i)] = i
            self.assertEqual(hf.pending, 8)
            seen = set()
            for _ in frames:
                done = hf.wait()
                self.assertEqual(done.status, "OK")
                self.assertEqual(ids[done.id], done.user)
                self.assertEqual(done.result.tobytes(), singles[done.user])
                seen.add(done.user)
            self.assertEqual(seen, set(range(8)))
            self.assertEqual(hf.pending, 0)
            with self.assertRaises(hairfilter.Error) as e:
                hf.wait(timeout=0.1)
            self.assertEqual(e.exception.code, "NOPENDING")
            after = {v.name: v.requests_ok for v in hf.stats().variants}
            self.assertEqual(after["Small"] - before["Small"], 8)
            # Every field where PROTOCOL.md puts it: each successful request
            # is in both histograms once; the version-2 counters follow them.
            small = {v.name: v for v in hf.stats().variants}["Small"]
            self.assertEqual(sum(small.hist_total), small.requests_ok)
            self.assertEqual(sum(small.hist_infer), small.requests_ok)
            self.assertLessEqual(small.out_of_range + small.frames_sanitised, 2 * small.requests_ok)
            self.assertIsInstance(small.cache_bytes, int)  # 0 on this server's cpu-ref backend

    def test_errors(self):
        f = features(8, 8, 4, 5)
        with hairfilter.Client(UNIX) as hf:
            with self.assertRaises(hairfilter.Error) as e:
                hf.filter("Smal", f)
            self.assertEqual(e.exception.code, "UNKNOWN_VARIANT")
            self.assertIn("Small", e.exception.message)
            self.assertIn(BASE1, e.exception.message)
            # Names match without regard to case, as in the C library.
            self.assertEqual(hf.filter("small", f).result.tobytes(),
                             hf.filter("Small", f).result.tobytes())
            with self.assertRaises(hairfilter.Error) as e:
                hf.filter("Small", f[:, :, :20])
            self.assertEqual(e.exception.code, "ARG")
            with self.assertRaises(hairfilter.Error) as e:
                hf.filter("Small", f.astype(np.float64))
            self.assertEqual(e.exception.code, "ARG")
            # A bad colour or an empty frame is an argument named, not a
            # struct or codec exception.
            for kw, word in (({"composite": True, "hair": (1, 2)}, "hair"),
                             ({"composite": True, "light": (1, float("nan"), 1)}, "light"),
                             ({"background": "grey"}, "background")):
                with self.assertRaises(hairfilter.Error) as e:
                    hf.filter("Small", f, **kw)
                self.assertEqual(e.exception.code, "ARG")
                self.assertIn(word, e.exception.message)
            with self.assertRaises(hairfilter.Error) as e:
                hf.filter("Small", np.zeros((0, 0, 24), np.float32))
            self.assertEqual(e.exception.code, "ARG")
            self.assertIn("features", e.exception.message)
            # spp not the variant's: refused before sending, naming both.
            with self.assertRaises(hairfilter.Error) as e:
                hf.filter(BASE1, f)
            self.assertEqual(e.exception.code, "ARG")
            self.assertIn("4 samples per pixel", e.exception.message)
            self.assertIn("takes 1 (Variant.spp)", e.exception.message)
            # The server's verdict on the same frame, the client's check off.
            check, hf._check_variant = hf._check_variant, lambda name, spp, given: None
            with self.assertRaises(hairfilter.Error) as e:
                hf.filter(BASE1, f)
            self.assertEqual(e.exception.code, "INVALID")
            hf._check_variant = check
            self.assertEqual(hf.filter("Small", f).status, "OK")
        missing = "unix:" + os.path.join(ARGS.work, "missing.sock")
        with self.assertRaises(hairfilter.Error) as e:
            hairfilter.Client(missing)
        self.assertEqual(e.exception.code, "CONNECT")
        self.assertIn("No such file", e.exception.message)
        self.assertIn("is hairfilterd running?", e.exception.message)
        with hairfilter.Client(missing + "," + UNIX) as hf:
            self.assertEqual(hf.endpoint, UNIX)
        with self.assertRaises(hairfilter.Error) as e:
            hairfilter.Client("tcp:host:99999")
        self.assertEqual(e.exception.code, "URL")

    def test_connection_limit(self):
        """A server at --max-connections answers the next connection with
        a fatal BUSY and closes it before reading the HELLO: the client
        reports BUSY naming the limit, not the failed send ('CLOSED: send:
        Broken pipe', which it said every time on a Unix socket)."""
        sock = os.path.join(ARGS.work, "limit.sock")
        if os.path.exists(sock):
            os.unlink(sock)
        proc, urls = start_daemon("limit", ["--listen", "unix:" + sock, "--weights",
                                            os.path.join(ARGS.weights, "small.safetensors"),
                                            "--max-connections", "1"])
        try:
            with hairfilter.Client(urls[0]):
                for _ in range(50):
                    with self.assertRaises(hairfilter.Error) as e:
                        hairfilter.Client(urls[0]).close()
                    self.assertEqual(e.exception.code, "BUSY", e.exception.message)
                    self.assertIn("connection limit (1)", e.exception.message)
        finally:
            proc.terminate()
            proc.wait(timeout=30)

    def test_closed_mid_frame(self):
        """A server that answers a frame from its header and closes while
        the client is still writing it (a draining server's SHUTTING_DOWN,
        a fatal TOO_LARGE): the frame completes with the server's answer,
        not as a lost connection. The mock replays the daemon's own
        HELLO_OK and VARIANTS."""
        hello_ok, variants = recorded_handshake()
        for code, fatal in ((P.E_SHUTTING_DOWN, 0), (P.E_TOO_LARGE, 1)):
            path, lsock = unix_listener("mock.sock", 1)

            def serve():
                s, _ = lsock.accept()
                s.settimeout(10)
                read_message(s)
                s.sendall(hello_ok)
                while True:
                    head = recv_exactly(s, 16)
                    type_, rid, length = P.decode_header(head)
                    if type_ == P.FILTER:
                        break
                    recv_exactly(s, length)
                    s.sendall(variants)
                msg = b"said the mock"
                s.sendall(P.frame(P.ERROR, struct.pack("<IBBH", code, fatal, 0, len(msg)) + msg,
                                  rid))
                s.close()   # the rest of the frame unread
                lsock.close()

            t = threading.Thread(target=serve)
            t.start()
            try:
                with hairfilter.Client("unix:" + path) as c:
                    # 256x256 at 4 spp: 6 MiB, far over a socket's buffers.
                    rid = c.submit("Small", features(256, 256, 4, 9))
                    d = c.wait()
                    self.assertEqual((d.id, d.status), (rid, P.code_name(code)), d.message)
                    self.assertIn("said the mock", d.message)
                    with self.assertRaises(hairfilter.Error):
                        c.submit("Small", features(8, 8, 4, 9))
            finally:
                t.join(30)

    def test_limits_refused_before_sending(self):
        """A frame over the limits HELLO_OK announced (16x16, an 8 KiB payload,
        f32 only) is refused by the client before a byte of it is written,
        naming the limit and the frame's size, and the connection goes on:
        the mock counts the FILTERs that reach it."""
        hello_ok, variants = recorded_handshake()
        hello_ok = bytearray(hello_ok)
        # HELLO_OK's max_width, max_height, dtypes and max_frame_bytes
        # (PROTOCOL.md), 16 header bytes in.
        struct.pack_into("<II", hello_ok, 16 + 4, 16, 16)
        struct.pack_into("<I", hello_ok, 16 + 16, 1)
        struct.pack_into("<Q", hello_ok, 16 + 28, 8192)
        path, lsock = unix_listener("limits.sock", 1)
        filters = []

        def serve():
            s, _ = lsock.accept()
            s.settimeout(10)
            read_message(s)
            s.sendall(hello_ok)
            try:
                while True:
                    head = recv_exactly(s, 16)
                    type_, rid, length = P.decode_header(head)
                    recv_exactly(s, length)
                    if type_ == P.FILTER:
                        filters.append(length)
                        msg = b"fake answer"
                        s.sendall(P.frame(P.ERROR, struct.pack("<IBBH", P.E_INTERNAL, 0, 0,
                                                               len(msg)) + msg, rid))
                    else:
                        s.sendall(variants)
            except EOFError:
                pass
            s.close()
            lsock.close()

        t = threading.Thread(target=serve)
        t.start()
        try:
            with hairfilter.Client("unix:" + path) as c:
                for f, code, says in (
                        (features(8, 32, 4, 1), "TOO_LARGE", ("32x8", "16x16", "max_width",
                                                               "--max-memory-mb",
                                                               "--max-frame-mb")),
                        (features(16, 16, 4, 1), "TOO_LARGE",
                         ("16x16 frame of 4 spp", "8192", "max_frame_bytes")),
                        (features(4, 4, 4, 1, np.float16), "UNSUPPORTED", ("float32",))):
                    with self.assertRaises(hairfilter.Error) as e:
                        c.submit("small", f)
                    self.assertEqual(e.exception.code, code, e.exception.message)
                    for word in says + ("nothing was sent",):
                        self.assertIn(word, e.exception.message)
                    self.assertEqual(c.pending, 0)
                with self.assertRaises(hairfilter.Error) as e:
                    c.filter("Small", features(8, 8, 4, 1))
                self.assertEqual(e.exception.code, "INTERNAL", e.exception.message)
                self.assertIn("fake answer", e.exception.message)
        finally:
            t.join(30)
        self.assertEqual(len(filters), 1, "FILTERs that reached the server: %s" % filters)

    def test_shm_limits_refused_before_sending(self):
        """A frame in shared memory over a real server's --max-size is
        refused before its reference goes out (the server counts no request
        of the variant), and one within it then goes by reference."""
        sock = os.path.join(ARGS.work, "small-size.sock")
        if os.path.exists(sock):
            os.unlink(sock)
        proc, urls = start_daemon("small-size", [
            "--listen", "unix:" + sock, "--max-size", "16x16",
            "--weights", os.path.join(ARGS.weights, "small.safetensors")])
        try:
            with hairfilter.Client("unix:" + sock) as c:
                f = features(32, 32, 4, 3)
                seg = c.shared_memory(f.nbytes + 32 * 32 * 3 * 4)
                fin = seg.array(f.shape, np.float32, 0)
                out = seg.array((32, 32, 3), np.float32, f.nbytes)
                fin[...] = f
                with self.assertRaises(hairfilter.Error) as e:
                    c.filter("Small", fin, result=out)
                self.assertEqual(e.exception.code, "TOO_LARGE", e.exception.message)
                self.assertIn("32x32", e.exception.message)
                self.assertIn("16x16", e.exception.message)
                v = [v for v in c.stats().variants if v.name == "Small"][0]
                self.assertEqual(v.rejected + v.requests_failed, 0)
                small = seg.array((16, 16, 24), np.float32, 0)
                small[...] = features(16, 16, 4, 3)
                done = c.filter("Small", small, result=seg.array((16, 16, 3), np.float32,
                                                                 small.nbytes))
                self.assertTrue(done.timing.via_shm)
                seg.close()
        finally:
            proc.terminate()
            self.assertEqual(proc.wait(timeout=30), 0)

    def test_connect_queue_full(self):
        """A Unix listener that accepts nothing, its queue of connections
        full: CONNECT after about the timeout, saying what to check (it was
        refused at once with "Resource temporarily unavailable")."""
        path, lsock = unix_listener("full.sock", 0)
        fill = []
        try:
            for _ in range(8):
                s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
                fill.append(s)
                s.setblocking(False)
                s.connect(path)
        except BlockingIOError:
            pass
        try:
            t0 = time.monotonic()
            with self.assertRaises(hairfilter.Error) as e:
                hairfilter.Client("unix:" + path, timeout=1)
            took = time.monotonic() - t0
            self.assertEqual(e.exception.code, "CONNECT", e.exception.message)
            self.assertIn("is hairfilterd stopped or overloaded", e.exception.message)
            self.assertTrue(0.5 < took < 5, took)
        finally:
            for s in fill:
                s.close()
            lsock.close()

    def test_segment_close_pending_and_bounds(self):
        """A segment whose close() is refused while a frame uses it stays
        the client's: later frames in it still go by reference (it was
        dropped from the client's list, and they went through the socket
        without a word). array() out of the segment is ARG naming the sizes
        (numpy's TypeError, or a view before the segment's start)."""
        with hairfilter.Client(UNIX) as c:
            seg = c.shared_memory(1 << 16)
            fin = seg.array((8, 8, 24), np.float32, 0)
            fin[...] = features(8, 8, 4, 2)
            out = seg.array((8, 8, 3), np.float32, fin.nbytes)
            c.submit("Small", fin, result=out)
            with self.assertRaises(hairfilter.Error) as e:
                seg.close()
            self.assertEqual(e.exception.code, "ARG")
            self.assertEqual(c.wait().status, "OK")
            self.assertTrue(c.filter("Small", fin, result=out).timing.via_shm)
            for offset in (1 << 16, (1 << 16) - 4, -4):
                with self.assertRaises(hairfilter.Error) as e:
                    seg.array((8, 8, 24), np.float32, offset)
                self.assertEqual(e.exception.code, "ARG")
                self.assertIn("run past", e.exception.message)
            seg.close()
            with self.assertRaises(hairfilter.Error):
                seg.array((1,), np.float32, 0)

    def test_lost_connection_completes_pending(self):
        """A server that goes with frames in flight: wait() returns each
        of them completed with the loss (pending counts down to 0), then
        raises it saying to connect again. wait() raised the loss for ever
        with pending stuck, so an engine's loop on pending never ended."""
        hello_ok, variants = recorded_handshake()
        path, lsock = unix_listener("gone.sock", 1)

        def serve():
            s, _ = lsock.accept()
            s.settimeout(10)
            read_message(s)
            s.sendall(hello_ok)
            filters = 0
            while filters < 3:
                type_, _, length = P.decode_header(recv_exactly(s, 16))
                recv_exactly(s, length)
                if type_ == P.FILTER:
                    filters += 1
                else:
                    s.sendall(variants)
            s.close()   # three frames owed, none answered
            lsock.close()

        t = threading.Thread(target=serve)
        t.start()
        try:
            with hairfilter.Client("unix:" + path) as c:
                for i in range(3):
                    c.submit("Small", features(8, 8, 4, i), user=i)
                users = []
                while c.pending:
                    d = c.wait()
                    self.assertEqual(d.status, "CLOSED", d.message)
                    self.assertIn("connect again", d.message)
                    users.append(d.user)
                self.assertEqual(sorted(users), [0, 1, 2])
                with self.assertRaises(hairfilter.Error) as e:
                    c.wait()
                self.assertEqual(e.exception.code, "CLOSED")
                self.assertIn("connect again", e.exception.message)
        finally:
            t.join(30)

    def test_close_after_server_gone(self):
        """close() (and leaving a with block) after the server went away,
        with a segment held: it closes and unmaps without raising. The
        segment's release was written to the dead socket, and the loss
        ('CLOSED: send: Broken pipe') came out of close(), leaving the
        segment mapped."""
        sock = os.path.join(ARGS.work, "gone_shm.sock")
        if os.path.exists(sock):
            os.unlink(sock)
        proc, urls = start_daemon("gone_shm", ["--listen", "unix:" + sock, "--weights",
                                               os.path.join(ARGS.weights, "small.safetensors")])
        try:
            c = hairfilter.Client(urls[0])
            seg = c.shared_memory(1 << 16)
        finally:
            proc.kill()
            proc.wait(timeout=30)
        c.close()
        self.assertIsNone(seg._mm)
        with self.assertRaises(hairfilter.Error):
            c.wait()

    def test_close_with_frame_pending_in_segment(self):
        """close() (and leaving a with block) while a frame in a shared
        segment is pending abandons it and closes: it raised ARG from the
        segment's release and left the socket open."""
        c = hairfilter.Client(UNIX)
        seg = c.shared_memory(1 << 20)
        fin = seg.array((32, 32, 24), np.float32, 0)
        fin[...] = features(32, 32, 4, 5)
        c.submit("Small", fin, result=seg.array((32, 32, 3), np.float32, fin.nbytes))
        c.close()
        with self.assertRaises(hairfilter.Error) as e:
            c.wait()
        self.assertEqual(e.exception.code, "CLOSED")

    def test_inflight_says_what_to_do(self):
        """A submit over the server's in-flight window is INFLIGHT naming
        the window and saying to collect with wait(); the frames in flight
        then complete."""
        with hairfilter.Client(UNIX) as c:
            f = features(8, 8, 4, 6)
            for _ in range(c.info.max_inflight):
                c.submit("Small", f)
            with self.assertRaises(hairfilter.Error) as e:
                c.submit("Small", f)
            self.assertEqual(e.exception.code, "INFLIGHT")
            self.assertIn("info.max_inflight", e.exception.message)
            self.assertIn("wait()", e.exception.message)
            while c.pending:
                c.wait()

    def test_deadline(self):
        """deadline_us (protocol version 4): a frame whose budget passes while
        a frame ahead of it holds the batcher completes EXPIRED, unrun, with
        a message naming the budget; one within its budget is served; STATS
        counts the expired one; a budget outside 1..2**32-1 is ARG."""
        sock = os.path.join(ARGS.work, "deadline.sock")
        if os.path.exists(sock):
            os.unlink(sock)
        d, _ = start_daemon("deadline", [
            "--listen", "unix:" + sock, "--max-batch", "16", "--max-queue-delay-us", "1500000",
            "--weights", os.path.join(ARGS.weights, "small.safetensors")])
        try:
            with hairfilter.Client("unix:" + sock) as c:
                self.assertEqual(c.info.version, 4)
                for bad in (0, -1, 2 ** 32, 1.5, True, "16000"):
                    with self.assertRaises(hairfilter.Error) as e:
                        c.submit("Small", features(8, 8, 4, 1), deadline_us=bad)
                    self.assertEqual(e.exception.code, "ARG")
                    self.assertIn("deadline_us", e.exception.message)
                held = c.submit("Small", features(8, 8, 4, 2))
                time.sleep(0.1)   # the batcher holds it, waiting for partners
                late = c.submit("Small", features(8, 12, 4, 3), deadline_us=150000)
                got = {}
                while c.pending:
                    x = c.wait()
                    got[x.id] = x
                self.assertEqual(got[held].status, "OK")
                self.assertEqual(got[late].status, "EXPIRED")
                self.assertIn("deadline_us", got[late].message)
                self.assertIn("budget of 150000 us", got[late].message)
                self.assertGreaterEqual(got[late].timing.queue_us, 150000)
                f = features(8, 12, 4, 4)
                ok = c.filter("Small", f, deadline_us=30000000)
                self.assertEqual(ok.status, "OK")
                self.assertEqual(ok.result.tobytes(), c_filter("unix:" + sock, "Small", f))
                small = [v for v in c.stats().variants if v.name == "Small"][0]
                self.assertEqual(small.expired, 1)
        finally:
            d.terminate()
            self.assertEqual(d.wait(timeout=30), 0)

    def test_cancel(self):
        """cancel() (protocol version 4): a frame queued behind one the
        batcher holds completes CANCELLED, first; the held one, cancelled
        too, runs and is served; an id not pending is ARG. Against a
        version-3 connection cancel() is UNSUPPORTED and the frame served."""
        sock = os.path.join(ARGS.work, "cancel.sock")
        if os.path.exists(sock):
            os.unlink(sock)
        d, _ = start_daemon("cancel", [
            "--listen", "unix:" + sock, "--max-batch", "16", "--max-queue-delay-us", "1500000",
            "--weights", os.path.join(ARGS.weights, "small.safetensors")])
        try:
            with hairfilter.Client("unix:" + sock) as c:
                f = features(8, 8, 4, 5)
                held = c.submit("Small", f)
                time.sleep(0.1)   # the batcher holds it, waiting for partners
                queued = c.submit("Small", features(8, 12, 4, 6))
                c.cancel(queued)
                c.cancel(held)
                first = c.wait()
                self.assertEqual((first.id, first.status), (queued, "CANCELLED"))
                self.assertIn("cancel()", first.message)
                second = c.wait()
                self.assertEqual((second.id, second.status), (held, "OK"))
                self.assertEqual(second.result.tobytes(), c_filter("unix:" + sock, "Small", f))
                with self.assertRaises(hairfilter.Error) as e:
                    c.cancel(held)
                self.assertEqual(e.exception.code, "ARG")
                # STATS counts the CANCELLED frame apart, and in
                # requests_failed as every status but OK
                small = [v for v in c.stats().variants if v.name == "Small"][0]
                self.assertEqual((small.cancelled, small.expired, small.requests_failed),
                                 (1, 0, 1))
        finally:
            d.terminate()
            self.assertEqual(d.wait(timeout=30), 0)
        real = P.encode_hello
        P.encode_hello = lambda name, token="": real(name, token, hi=3)
        try:
            with hairfilter.Client(UNIX) as c:
                rid = c.submit("Small", features(8, 8, 4, 7))
                with self.assertRaises(hairfilter.Error) as e:
                    c.cancel(rid)
                self.assertEqual(e.exception.code, "UNSUPPORTED")
                self.assertEqual(c.wait().status, "OK")
        finally:
            P.encode_hello = real

    def test_deadline_older_server(self):
        """Against a connection of version 3 a budget is not sent: a frame
        with deadline_us=1 (which would expire on version 4) is served."""
        real = P.encode_hello
        P.encode_hello = lambda name, token="": real(name, token, hi=3)
        try:
            with hairfilter.Client(UNIX) as c:
                self.assertEqual(c.info.version, 3)
                f = features(8, 8, 4, 9)
                done = c.filter("Small", f, deadline_us=1)
                self.assertEqual(done.status, "OK")
                self.assertEqual(done.result.tobytes(), c_filter(UNIX, "Small", f))
        finally:
            P.encode_hello = real

    def test_codec_deadline(self):
        """FILTER flag DEADLINE and the budget right after the name; STATS'
        fourth counter is expired, the fifth cancelled."""
        head = P.encode_filter_head(5, "Small", 2, 1, 4, P.F32, P.F32, budget_us=16000)
        body = head[P.HEADER_SIZE:]
        self.assertEqual(struct.unpack_from("<H", body, 2)[0], P.FILTER_DEADLINE)
        at = P.FILTER_FIXED.size + len("Small")
        self.assertEqual(len(body), at + 4)
        self.assertEqual(struct.unpack_from("<I", body, at)[0], 16000)
        _, _, length = P.decode_header(head[:P.HEADER_SIZE])
        self.assertEqual(length, at + 4 + 2 * 1 * 4 * 6 * 4)
        plain = P.encode_filter_head(5, "Small", 2, 1, 4, P.F32, P.F32)
        self.assertEqual(len(plain), len(head) - 4)
        for bad in (-1, 2 ** 32):
            with self.assertRaises(ValueError):
                P.encode_filter_head(5, "Small", 2, 1, 4, P.F32, P.F32, budget_us=bad)
        self.assertEqual(P.code_name(P.E_EXPIRED), "EXPIRED")
        # STATS_REPLY of one variant with 4, 5 and 6 counters: a server
        # that sends four has no cancelled (0); a sixth is skipped
        entry = bytes([5]) + b"Small" + struct.pack("<7Q", 1, 2, 0, 1, 0, 0, 0) + \
            struct.pack("<48Q", *([0] * 48))
        head = struct.pack("<QQIIIQHH", 1, 1, 1, 0, 64, 0, 1, 24)
        for nc, cancelled in ((4, 0), (5, 15), (6, 15)):
            counters = struct.pack("<H%dQ" % nc, nc, *(11, 12, 13, 14, 15, 16)[:nc])
            v = P.decode_stats(head + entry + counters).variants[0]
            self.assertEqual((v.expired, v.cancelled, v.requests_failed), (14, cancelled, 2))

    def test_codec(self):
        hello = P.encode_hello("py", "tok")
        self.assertEqual(P.decode_header(hello[:16]), (P.HELLO, 0, len(hello) - 16))
        with self.assertRaises(P.ProtocolError) as e:
            P.decode_error(bytes([11, 0, 0, 0, 0, 0, 5, 0]) + b"abc")
        self.assertEqual(e.exception.code, P.E_LENGTH)
        for bad in ("tcp:h:0", "tcp:h:65536", "tcp:h:7070x", "tcp:::1:80", "unix:", "udp:1"):
            with self.assertRaises(ValueError):
                P.parse_url(bad)
        self.assertEqual(P.parse_url("tcp:[::1]:7070"), P.Address("tcp", None, "::1", 7070))
        self.assertEqual(P.parse_url("tcp:7070").host, "127.0.0.1")
        self.assertEqual(P.parse_url("tls:render-07:7443"),
                         P.Address("tls", None, "render-07", 7443))
        with self.assertRaises(ValueError):
            P.parse_url("tls://render-07:7443")


def main():
    global ARGS
    ap = argparse.ArgumentParser()
    ap.add_argument("--daemon", required=True)
    ap.add_argument("--filter-raw", required=True)
    ap.add_argument("--weights", required=True)
    ap.add_argument("--version", required=True)
    ap.add_argument("--work", required=True)
    ap.add_argument("--make-certs", required=True)
    ARGS, rest = ap.parse_known_args()
    shutil.rmtree(ARGS.work, ignore_errors=True)
    unittest.main(argv=[sys.argv[0]] + rest, verbosity=2)


if __name__ == "__main__":
    main()
