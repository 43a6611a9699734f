"""TLS for the server tests that must stop a handshake half-way or replay
one (docs/SERVER.md, "Handshakes and slow peers"): hairfilterd on a tls:
listener, a TLS client driven by hand over memory BIOs, a recorded
ClientHello and bursts of connections that send it."""
import os
import select
import socket
import ssl
import struct
import subprocess
import time

from rawwire import ERROR, HELLO, HELLO_OK, frame, ready_ports, wait_ready


def start_tls(binary, weights, w, certs, args, key="server"):
    """hairfilterd (binary) on tls:127.0.0.1:0 with the cpu backend,
    WEIGHTS/small.safetensors, certs/KEY.pem and certs/KEY.key and args,
    its log in w/daemon.log: (process, TLS port) once its ready file is
    there, or (process, None) when it exited or was not ready in 60 s."""
    ready = os.path.join(w, "ready")
    with open(os.path.join(w, "daemon.log"), "w") as log:
        proc = subprocess.Popen(
            [binary, "--config", "none", "--backend", "cpu", "--ready-file", ready,
             "--weights", os.path.join(weights, "small.safetensors"),
             "--listen", "tls:127.0.0.1:0", "--tls-cert", os.path.join(certs, key + ".pem"),
             "--tls-key", os.path.join(certs, key + ".key")] + args,
            stdout=log, stderr=subprocess.STDOUT)
    if not wait_ready(proc, ready):
        return proc, None
    return proc, ready_ports(w, "tls")[0]


class Tls:
    """A TLS client of 127.0.0.1:port (from source address src, when
    given) that trusts the CA file ca, driven by hand over memory BIOs so
    that it can stop in the middle of its handshake."""

    def __init__(self, port, ca, src=None, timeout=10):
        ctx = ssl.create_default_context(cafile=ca)
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=timeout,
                                             source_address=(src, 0) if src else None)
        self.inc, self.out = ssl.MemoryBIO(), ssl.MemoryBIO()
        self.obj = ctx.wrap_bio(self.inc, self.out, server_hostname="localhost")

    def step(self):
        """One handshake step: 1 when it is done, else 0 (bytes to send
        are in self.out)."""
        try:
            self.obj.do_handshake()
            return 1
        except ssl.SSLWantReadError:
            return 0

    def flush(self):
        """Sends what TLS has to send."""
        data = self.out.read()
        if data:
            self.sock.sendall(data)

    def feed(self):
        """Reads what the daemon sent into TLS; EOFError once it closed."""
        data = self.sock.recv(65536)
        if not data:
            raise EOFError("the daemon closed the connection")
        self.inc.write(data)

    def handshake(self):
        """Ends the handshake, wherever it stopped."""
        while not self.step():
            self.flush()
            self.feed()
        self.flush()

    def send(self, data):
        """Sends data over TLS."""
        self.obj.write(data)
        self.flush()

    def recv(self, n):
        """n bytes over TLS."""
        out = b""
        while len(out) < n:
            try:
                out += self.obj.read(n - len(out))
            except ssl.SSLWantReadError:
                self.feed()
        return out

    def hello(self, token=b""):
        """Says HELLO (with token): "HELLO_OK", or what came instead."""
        self.send(frame(HELLO, struct.pack("<HHHH", 1, 3, 4, len(token)) + b"test" + token))
        _, t, _, _, n = struct.unpack("<IHHII", self.recv(16))
        p = self.recv(n)
        if t == ERROR:
            return "ERROR %d: %s" % (struct.unpack("<I", p[:4])[0],
                                     p[8:].decode(errors="replace"))
        return "HELLO_OK" if t == HELLO_OK else "type %d" % t


def client_hello():
    """The bytes of one ClientHello, made once: a peer replays them and
    does no cryptography of its own."""
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.check_hostname = False
    ctx.verify_mode = ssl.CERT_NONE
    inc, out = ssl.MemoryBIO(), ssl.MemoryBIO()
    obj = ctx.wrap_bio(inc, out, server_hostname="localhost")
    try:
        obj.do_handshake()
    except ssl.SSLWantReadError:
        pass
    return out.read()


def burst(port, data, n, wait_s):
    """n connections from 127.0.0.1 to port, opened at once, each sending
    data once connected, for wait_s at most: (the sockets, how many sent
    data). A connection refused or reset is passed over: the daemon being
    behind, or closing it, is what the callers look for."""
    socks = []
    for _ in range(n):
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.setblocking(False)
        s.connect_ex(("127.0.0.1", port))
        socks.append(s)
    sent = 0
    pending, until = set(socks), time.time() + wait_s
    while pending and time.time() < until:
        _, ready, _ = select.select([], list(pending), [], max(0.0, until - time.time()))
        for s in ready:
            pending.discard(s)
            try:
                if s.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR) == 0:
                    s.send(data)
                    sent += 1
            except OSError:
                pass
    return socks, sent
