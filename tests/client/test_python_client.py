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
import subprocess
import sys
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


def c_filter(url, variant, f, shm=False, rgba=False, ca=None):
    """The C library's result (and composite) of frame f, as bytes."""
    h, w, ch = f.shape
    dt = "f16" if f.dtype == np.float16 else "f32"
    src = os.path.join(ARGS.work, "in.raw")
    dst = os.path.join(ARGS.work, "out.raw")
    drgba = os.path.join(ARGS.work, "rgba.raw")
    f.tofile(src)
    cmd = [ARGS.filter_raw, url, variant, str(w), str(h), str(ch // 6), dt, src, dst]
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


def setUpModule():
    global DAEMON, UNIX, TCP, TLS, CERTS
    os.makedirs(ARGS.work, exist_ok=True)
    CERTS = os.path.join(ARGS.work, "certs")
    os.makedirs(CERTS, exist_ok=True)
    subprocess.run([ARGS.make_certs, CERTS], check=True)
    ready = os.path.join(ARGS.work, "ready")
    sock = os.path.join(ARGS.work, "d.sock")
    for p in (ready, sock):
        if os.path.exists(p):
            os.unlink(p)
    log = open(os.path.join(ARGS.work, "daemon.log"), "w")
    DAEMON = subprocess.Popen(
        [ARGS.daemon, "--listen", "unix:" + sock, "--listen", "tcp:127.0.0.1:0", "--no-auth",
         "--listen", "tls:127.0.0.1:0", "--tls-cert", os.path.join(CERTS, "server.pem"),
         "--tls-key", os.path.join(CERTS, "server.key"),
         "--weights", os.path.join(ARGS.weights, "small.safetensors"),
         "--weights", os.path.join(ARGS.weights, "base_1spp.safetensors"),
         "--backend", "cpu-ref", "--ready-file", ready], stdout=log, stderr=log)
    for _ in range(3000):
        if os.path.exists(ready):
            urls = open(ready).read().split()
            UNIX = [u for u in urls if u.startswith("unix:")][0]
            TCP = [u for u in urls if u.startswith("tcp:")][0]
            # The certificate names localhost only.
            TLS = "tls:localhost:" + [u for u in urls if u.startswith("tls:")][0].rsplit(":", 1)[1]
            return
        if DAEMON.poll() is not None:
            break
        time.sleep(0.01)
    raise RuntimeError("hairfilterd did not start: see %s/daemon.log" % ARGS.work)


def tearDownModule():
    DAEMON.terminate()
    if DAEMON.wait(timeout=30) != 0:
        raise RuntimeError("hairfilterd exited with %d" % DAEMON.returncode)


class PythonClient(unittest.TestCase):
    def test_handshake_and_variants(self):
        with hairfilter.Client(UNIX, client_name="py-test") as hf:
            self.assertEqual(hf.info.version, 2)
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

    def test_tls_refusals(self):
        """A CA that did not sign the server's certificate, a host name it
        does not carry, a plain client on the TLS port: each named."""
        other = os.path.join(CERTS, "other-ca.pem")
        with self.assertRaises(hairfilter.Error) as e:
            hairfilter.Client(TLS, tls_ca=other)
        self.assertIn("unable to get local issuer certificate", str(e.exception))
        ca = os.path.join(CERTS, "ca.pem")
        with self.assertRaises(hairfilter.Error) as e:
            hairfilter.Client(TLS, tls_ca=ca, tls_server_name="render-99.farm")
        self.assertIn("Hostname mismatch", str(e.exception))
        with self.assertRaises(hairfilter.Error) as e:
            hairfilter.Client("tcp:" + TLS[4:])
        self.assertIn("this listener speaks TLS", str(e.exception))
        with hairfilter.Client(TLS, tls_ca=ca) as hf:
            self.assertEqual(hf.filter("Small", features(8, 8, 4, 3)).status, "OK")

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
            seg = hf.shared_memory(f.nbytes + 32 * 32 * 3 * 4)
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
            # The server's verdict: spp not the variant's.
            with self.assertRaises(hairfilter.Error) as e:
                hf.filter(BASE1, f)
            self.assertEqual(e.exception.code, "INVALID")
            self.assertEqual(hf.filter("Small", f).status, "OK")
        missing = "unix:" + os.path.join(ARGS.work, "missing.sock")
        with self.assertRaises(hairfilter.Error) as e:
            hairfilter.Client(missing)
        self.assertEqual(e.exception.code, "CONNECT")
        self.assertIn("No such file", e.exception.message)
        with hairfilter.Client(missing + "," + UNIX) as hf:
            self.assertEqual(hf.endpoint, UNIX)
        with self.assertRaises(hairfilter.Error) as e:
            hairfilter.Client("tcp:host:99999")
        self.assertEqual(e.exception.code, "URL")

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
